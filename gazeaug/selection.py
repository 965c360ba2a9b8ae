"""Time filters of a gaze stream: One-Euro smoothing, and selection of a target by dwell.

Both take timestamps (seconds), not frame counts, so they behave the same at
any frame rate and across dropped frames.

**One-Euro filter** (Casiez, Roussel and Vogel, CHI 2012): an exponential
smoother whose cut-off frequency rises with the signal's speed, so a still
gaze is steady and a saccade is followed without lag. Per sample, with
``dt`` the time since the previous one and ``a(fc) = 1 / (1 + 1 / (2 pi fc dt))``:
``dx = a(d_cutoff) (x - x_prev) / dt + (1 - a(d_cutoff)) dx_prev``,
``fc = min_cutoff + beta |dx|``, ``x_hat = a(fc) x + (1 - a(fc)) x_hat_prev``.
The first sample, and the first after a gap longer than ``reset_after_s``, is
passed through.

**Dwell selection with hysteresis**: a target is *selected* when the gaze has
stayed on it for ``dwell_s``; looking away (or a frame without gaze: a blink,
no face) for at most ``gap_s`` neither ends the dwell nor starts another
target's; after a selection the same target is selected again only after the
gaze has left it for longer than ``gap_s``. When the gaze has been elsewhere for
longer than ``gap_s``, the dwell restarts on whatever it is on now, counted
from the first frame of its current unbroken run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import GazeAugError

__all__ = [
    "SmoothingSettings",
    "OneEuroFilter",
    "SelectionSettings",
    "Selection",
    "DwellSelector",
    "MAX_MARGIN_DEG",
    "MAX_DWELL_S",
]

#: The largest angular margin of a target: a margin grows each target by ``distance x tan(margin)``,
#: and beyond some 20 deg nearby targets grow over the face and catch every gaze.
MAX_MARGIN_DEG = 20.0
#: The longest dwell, seconds.
MAX_DWELL_S = 60.0


def _positive(name: str, value: float, allow_zero: bool = False) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value < 0 or (value == 0 and not allow_zero):
        raise GazeAugError(f"{name}: expected a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class SmoothingSettings:
    """One-Euro filter settings (module docstring); the signal is gaze (pitch, yaw) in degrees.

    Attributes:
        min_cutoff_hz: cut-off of a still gaze (lower: steadier, more lag). Default 1.0 Hz.
        beta: how much the cut-off rises per deg/s of gaze speed. Default 0.02 (a 300 deg/s
            saccade: 7 Hz).
        d_cutoff_hz: cut-off of the speed estimate. Default 1.0 Hz.
        reset_after_s: a gap between samples longer than this restarts the filter. Default 0.5 s.
    """

    min_cutoff_hz: float = 1.0
    beta: float = 0.02
    d_cutoff_hz: float = 1.0
    reset_after_s: float = 0.5

    def __post_init__(self) -> None:
        _positive("min_cutoff_hz", self.min_cutoff_hz)
        _positive("beta", self.beta, allow_zero=True)
        _positive("d_cutoff_hz", self.d_cutoff_hz)
        _positive("reset_after_s", self.reset_after_s)


def _alpha(cutoff_hz: float, dt: float) -> float:
    return 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff_hz * dt))


class OneEuroFilter:
    """One-Euro filter over a vector signal (every component filtered alike, one shared speed).

    Args:
        settings: :class:`SmoothingSettings`.
    """

    def __init__(self, settings: SmoothingSettings = SmoothingSettings()):
        self.settings = settings
        self._t: float | None = None
        self._x: NDArray[np.float64] | None = None
        self._dx = 0.0

    def reset(self) -> None:
        """Forget the past: the next sample passes through."""
        self._t, self._x, self._dx = None, None, 0.0

    def __call__(self, t_s: float, x: ArrayLike) -> NDArray[np.float64]:
        """Filter one sample taken at ``t_s`` (seconds, increasing): (D,) float -> (D,) float64."""
        v = np.asarray(x, dtype=np.float64).copy()
        s = self.settings
        if self._t is None or self._x is None or not (0 < t_s - self._t <= s.reset_after_s):
            self._t, self._x, self._dx = float(t_s), v, 0.0
            return v.copy()
        dt = float(t_s) - self._t
        speed = float(np.linalg.norm(v - self._x)) / dt
        a_d = _alpha(s.d_cutoff_hz, dt)
        self._dx = a_d * speed + (1 - a_d) * self._dx
        a = _alpha(s.min_cutoff_hz + s.beta * self._dx, dt)
        self._x = a * v + (1 - a) * self._x
        self._t = float(t_s)
        return self._x.copy()


@dataclass(frozen=True)
class SelectionSettings:
    """Dwell selection settings (module docstring).

    Attributes:
        dwell_s: how long the gaze must stay on a target to select it. Default 0.6 s.
        gap_s: the longest look-away (or blink) that does not end a dwell. Default 0.15 s.
        margin_deg: the angular margin a target is looked at with (:mod:`gazeaug.scene`). Default 5 deg,
            at most :data:`MAX_MARGIN_DEG`.
    """

    dwell_s: float = 0.6
    gap_s: float = 0.15
    margin_deg: float = 5.0

    def __post_init__(self) -> None:
        if _positive("dwell_s", self.dwell_s) > MAX_DWELL_S:
            raise GazeAugError(f"dwell_s: expected at most {MAX_DWELL_S:g} s, got {self.dwell_s}")
        _positive("gap_s", self.gap_s, allow_zero=True)
        m = _positive("margin_deg", self.margin_deg, allow_zero=True)
        if m > MAX_MARGIN_DEG:
            raise GazeAugError(f"margin_deg: expected at most {MAX_MARGIN_DEG:g} deg, got {m}")


@dataclass(frozen=True)
class Selection:
    """A selection event: ``target`` chosen at ``time_s`` (frame ``frame``) after a dwell that began at ``start_s``."""

    target: str
    frame: int
    time_s: float
    start_s: float


class DwellSelector:
    """Turns the per-frame target looked at into selection events (module docstring).

    Call :meth:`update` once per frame, in time order, with the target looked at
    (``None``: nothing, or no gaze this frame); it returns the selection made at
    that frame, if any. :attr:`current` and :meth:`progress` describe the dwell.
    """

    def __init__(self, settings: SelectionSettings = SelectionSettings()):
        self.settings = settings
        self.current: str | None = None  # the target the dwell is on
        self._start = 0.0  # when the dwell on ``current`` began
        self._last_on = -math.inf  # the last time the gaze was on ``current``
        self._fired = False  # ``current`` was selected during this dwell
        self._run: str | None = None  # the raw target of the latest frames, and when that run began
        self._run_start = 0.0
        self._t = -math.inf

    def update(self, frame: int, t_s: float, target: str | None) -> Selection | None:
        """The target looked at in ``frame`` at ``t_s`` -> a :class:`Selection` made now, or None."""
        if t_s < self._t:
            raise GazeAugError(f"dwell selection: time went backwards ({t_s} s after {self._t} s)")
        self._t = t_s
        if target != self._run:
            self._run, self._run_start = target, t_s
        gap = self.settings.gap_s
        if target is not None and target == self.current:
            self._last_on = t_s
        elif self.current is None or t_s - self._last_on > gap:
            # the dwell (if any) has ended: start on what the gaze is on now, from its run's first frame
            self.current, self._fired = target, False
            self._start = self._run_start
            self._last_on = t_s if target is not None else -math.inf
        if self.current is not None and not self._fired and self._last_on == t_s:
            if t_s - self._start >= self.settings.dwell_s - 1e-9:
                self._fired = True
                return Selection(self.current, frame, t_s, self._start)
        return None

    def progress(self, t_s: float) -> float:
        """How far the dwell on :attr:`current` is at ``t_s``: 0..1 (1 once selected)."""
        if self.current is None:
            return 0.0
        if self._fired:
            return 1.0
        return float(min(1.0, max(0.0, (t_s - self._start) / self.settings.dwell_s)))
