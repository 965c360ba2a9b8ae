"""Simulated gaze *sequences* with exact ground truth: one subject looking at a rig's targets over time.

``gazeaug simulate --sequence SECONDS --rig RIG.yaml -o seq/`` writes frames at a
fixed rate of one simulated subject (:class:`gazeaug.simulate.SimSubject`, its
identity drawn from the seed) who

- **fixates** the rig's targets (:mod:`gazeaug.scene`) in random order (never the same
  one twice in a row), each for ``fixation_s`` seconds, looking at its centre;
- **glances** at other points of the rig's ``target_box_mm`` between them (a share
  ``glance_share`` of the fixations, each ``glance_s`` long: shorter than a dwell, at
  least ``glance_clearance_deg`` away from every target's centre), which a selection
  interface must not take for a choice;
- **saccades** from one point to the next in ``saccade_s`` (the gaze point moves in a
  straight line);
- **moves the head** smoothly: yaw, pitch and position are sums of slow sinusoids
  (``head_band_hz``) with the rig's means and spreads;
- **blinks** every ``blink_every_s`` seconds for ``blink_s`` (the upper lids lowered
  onto the lower ones; ``SimSubject.render(blink=...)``).

The folder holds the frames (``00000.jpg``, ...; what ``gazeaug track`` reads,
in name order), ``sequence.json`` (frame rate, rig, settings, subject), ``truth.csv``
(per frame: ``frame, time_s, phase`` (``fixation``, ``glance``, ``saccade``),
``target`` (the target fixated, empty otherwise), ``blink`` (0..1), the point looked
at in the rig frame ``point_x_mm, point_y_mm, point_z_mm`` and in the camera frame
``target_x, target_y, target_z`` (mm), and the head's ``head_yaw_deg, head_pitch_deg``
(rig frame)), ``labels.csv`` (the folder-dataset format, so ``gazeaug evaluate``
reads it too) and ``simulation.jsonl`` (everything the simulator drew, per frame).

:func:`sequence_accuracy` compares ``gazeaug track``'s output with the truth: the
gaze error (degrees; and millimetres at the distance of the point looked at), and
the selections: right target, missed fixations, false selections per minute.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import GazeAugError
from .sampling import Rig

__all__ = ["SequenceSettings", "simulate_sequence", "read_truth", "sequence_accuracy", "TRUTH_COLUMNS"]

#: What a sequence's subject looks at (:class:`SequenceSettings`).
PATTERNS = ("targets", "calibration")
#: The calibration pattern's grid over the target box: shares of its x and y extent.
CALIBRATION_GRID = (0.1, 0.5, 0.9)

#: The columns of ``truth.csv`` (module docstring).
TRUTH_COLUMNS = (
    "frame",
    "time_s",
    "phase",
    "target",
    "blink",
    "point_x_mm",
    "point_y_mm",
    "point_z_mm",
    "target_x",
    "target_y",
    "target_z",
    "head_yaw_deg",
    "head_pitch_deg",
)


def _range(name: str, v: Any, low: float = 0.0) -> tuple[float, float]:
    if not (isinstance(v, (tuple, list)) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v)):
        raise GazeAugError(f"{name}: expected (low, high), got {v!r}")
    a, b = float(v[0]), float(v[1])
    if not (math.isfinite(a) and math.isfinite(b) and low < a <= b):
        raise GazeAugError(f"{name}: expected {low} < low <= high, got {v!r}")
    return a, b


@dataclass(frozen=True)
class SequenceSettings:
    """How a sequence unfolds (module docstring). Durations in seconds.

    Attributes:
        seconds: length (default 20).
        fps: frames per second (default 30).
        fixation_s: a fixation on a target lasts uniformly this long (default 1.0-2.0).
        glance_s: a glance elsewhere lasts this long (default 0.2-0.4: shorter than the default dwell).
        glance_share: the share of fixations that are glances (default 0.3).
        glance_clearance_deg: a glance point lies at least this far from every target's centre,
            seen from the eyes (default 12).
        saccade_s: the move from one point to the next (default 0.05).
        blink_every_s: the time between blinks is uniform in this range (default 2.0-6.0).
        blink_s: a blink's length (default 0.15; the lids close and open again, a triangle in time).
        pattern: ``targets`` (default: the module docstring's fixations and glances) or ``calibration``
            (a 3 x 3 grid of points over the rig's ``target_box_mm``, at 10-90 % of its x and y
            extent and the middle of its z, looked at in reading order, each for ``fixation_s``,
            repeated until ``seconds``: what ``gazeaug calibrate`` fits a user's correction to).
        head_band_hz: the head moves at frequencies in this band (default 0.05-0.4 Hz), with the rig's
            spreads.
    """

    seconds: float = 20.0
    fps: float = 30.0
    fixation_s: tuple[float, float] = (1.0, 2.0)
    glance_s: tuple[float, float] = (0.2, 0.4)
    glance_share: float = 0.3
    glance_clearance_deg: float = 12.0
    saccade_s: float = 0.05
    blink_every_s: tuple[float, float] = (2.0, 6.0)
    blink_s: float = 0.15
    head_band_hz: tuple[float, float] = (0.05, 0.4)
    pattern: str = "targets"

    def __post_init__(self) -> None:
        for name in ("seconds", "fps", "saccade_s", "blink_s", "glance_clearance_deg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0):
                raise GazeAugError(f"sequence {name}: expected a number > 0, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.seconds > 3600 or self.fps > 240:
            raise GazeAugError(f"sequence: at most 3600 s at 240 fps, got {self.seconds} s at {self.fps} fps")
        for name in ("fixation_s", "glance_s", "blink_every_s", "head_band_hz"):
            object.__setattr__(self, name, _range(f"sequence {name}", getattr(self, name)))
        if self.pattern not in PATTERNS:
            raise GazeAugError(f"sequence pattern: expected one of {PATTERNS}, got {self.pattern!r}")
        if not (isinstance(self.glance_share, (int, float)) and 0 <= self.glance_share < 1):
            raise GazeAugError(f"sequence glance_share: expected a number from 0 to below 1, got {self.glance_share!r}")

    @property
    def frames(self) -> int:
        """Frames in the sequence: ``round(seconds * fps)``, at least 1."""
        return max(1, int(round(self.seconds * self.fps)))


def _smooth_motion(
    rng: np.random.Generator, times: NDArray[np.float64], sd: float, dims: int, band_hz: tuple[float, float], k: int = 6
) -> NDArray[np.float64]:
    """Smooth random motion: (len(times), dims), mean 0, standard deviation ``sd`` per dimension.

    A sum of ``k`` sinusoids per dimension with frequencies uniform in ``band_hz`` and random phases,
    each of amplitude ``sd sqrt(2 / k)`` (a sinusoid's variance is half its squared amplitude).
    """
    f = rng.uniform(band_hz[0], band_hz[1], (k, dims))
    phase = rng.uniform(0, 2 * math.pi, (k, dims))
    waves = np.sin(2 * math.pi * f[None] * times[:, None, None] + phase[None])
    return sd * math.sqrt(2.0 / k) * waves.sum(axis=1)


def _schedule(
    rig: Rig, seq: SequenceSettings, rng: np.random.Generator
) -> list[tuple[float, str, str, NDArray[np.float64]]]:
    """Fixations and glances: (start_s, phase, target name or '', point, rig frame mm), covering the sequence."""
    targets = list(rig.targets)
    lo, hi = (np.asarray(c) for c in rig.target_box_mm)
    out: list[tuple[float, str, str, NDArray[np.float64]]] = []
    t, last = 0.0, ""
    if seq.pattern == "calibration":
        grid = [
            np.array([lo[0] + fx * (hi[0] - lo[0]), lo[1] + fy * (hi[1] - lo[1]), (lo[2] + hi[2]) / 2])
            for fy in CALIBRATION_GRID
            for fx in CALIBRATION_GRID
        ]
        while t < seq.seconds:
            out.append((t, "fixation", f"p{len(out) % 9 + 1}", grid[len(out) % 9]))
            t += rng.uniform(*seq.fixation_s)
        return out
    while t < seq.seconds:
        if out and rng.random() < seq.glance_share:
            for _ in range(200):
                p = rng.uniform(lo, hi)
                u = p / np.linalg.norm(p)
                if all(
                    math.degrees(math.acos(np.clip(u @ (tg.centre / np.linalg.norm(tg.centre)), -1, 1)))
                    >= seq.glance_clearance_deg
                    for tg in targets
                ):
                    break
            else:
                raise GazeAugError(
                    f"rig {rig.name!r}: no point of target_box_mm lies {seq.glance_clearance_deg} deg from every "
                    "target; lower glance_share or glance_clearance_deg"
                )
            out.append((t, "glance", "", p))
            t += rng.uniform(*seq.glance_s)
        else:
            choices = [tg for tg in targets if tg.name != last] or targets
            tg = choices[int(rng.integers(len(choices)))]
            out.append((t, "fixation", tg.name, tg.centre.copy()))
            last = tg.name
            t += rng.uniform(*seq.fixation_s)
    return out


def simulate_sequence(
    face: Any,
    rig: Rig,
    out_dir: str | Path,
    *,
    sequence: SequenceSettings = SequenceSettings(),
    seed: int = 0,
    identity_seed: int | None = None,
    settings: Any = None,
    overwrite: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Write one simulated subject's gaze sequence (module docstring) into ``out_dir``.

    Args:
        face: a face photo (path), a :class:`gazeaug.faces.FaceSource`, or None (the built-in astronaut).
        rig: a rig with targets (:attr:`Rig.targets`): the camera, the head's motion, what is looked at.
        out_dir: the folder to create (written beside it and swapped in when complete).
        sequence: :class:`SequenceSettings`.
        seed: everything random derives from it, except the subject's identity.
        identity_seed: the subject's identity (:func:`gazeaug.simulate.draw_subject`) derives from it
            (default: ``seed``): sequences of one person with other seeds (a calibration, a test).
        settings: :class:`gazeaug.simulate.SimSettings` (default: its defaults).
        overwrite: replace a sequence folder written before.
        progress: a progress bar.

    Returns:
        A summary: ``output``, ``frames``, ``fps``, ``seconds``, ``fixations``, ``glances``, ``blinks``.

    Raises:
        GazeAugError: a rig without targets; ``settings.texture_mix_share`` above 0 (one person).
        OutputError: ``out_dir`` is not empty (without ``overwrite``).
    """
    from facemesh.io import atomic_write, save_image_rgb
    from facemesh.outputs import staged_folder

    from .datasets.folder import write_labels_csv
    from .pipeline import default_landmark_model
    from .simulate import PhotoFace, SimSettings, SimSubject, _in_rig_camera, draw_subject, face_image, label_row

    if not rig.targets and sequence.pattern == "targets":  # the calibration grid needs none
        raise GazeAugError(f"rig {rig.name!r}: a sequence needs a rig with targets (see data_samples/rigs/)")
    s = settings or SimSettings()
    if s.texture_mix_share > 0:
        raise GazeAugError("texture mixing mixes the skin of several people; a sequence simulates one")
    seq = sequence
    rng = np.random.default_rng([seed, 7])
    image, source, _ = face_image(face)
    n, dt = seq.frames, 1.0 / seq.fps
    schedule = _schedule(rig, seq, rng)
    times = np.arange(n) * dt
    head = _smooth_motion(rng, times, 1.0, 2, seq.head_band_hz) * [rig.head_yaw_std_deg, rig.head_pitch_std_deg]
    head += [rig.head_yaw_mean_deg, rig.head_pitch_mean_deg]
    pos = _smooth_motion(rng, times, rig.head_position_std_mm, 3, seq.head_band_hz)
    blinks, tb = [], float(rng.uniform(*seq.blink_every_s))
    while tb < seq.seconds:
        blinks.append(tb)
        tb += seq.blink_s + float(rng.uniform(*seq.blink_every_s))
    k = np.array(rig.camera().matrix)
    w, h = rig.image_size_wh
    with staged_folder(out_dir, overwrite=overwrite, marker="sequence.json") as part:
        photo = PhotoFace.from_image(image, default_landmark_model(), source)
        ident = seed if identity_seed is None else identity_seed
        subject = SimSubject(photo, "seq", s, draw_subject(s, np.random.default_rng([ident, 0, 10**6])))
        rows, truth, labels = [], [], []
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=n, unit="frame", desc="simulate", dynamic_ncols=True)
        j = 0
        for i in range(n):
            t = i * dt
            while j + 1 < len(schedule) and schedule[j + 1][0] <= t:
                j += 1
            start, phase, name, point = schedule[j]
            if j > 0 and t - start < seq.saccade_s:  # moving from the previous point
                f = (t - start) / seq.saccade_s
                point = (1 - f) * schedule[j - 1][3] + f * point
                phase, name = "saccade", ""
            blink = max((1 - abs(t - b - seq.blink_s / 2) / (seq.blink_s / 2) for b in blinks), default=0.0)
            blink = float(np.clip(blink, 0.0, 1.0))
            r, tr, target = _in_rig_camera(rig, float(head[i, 0]), float(head[i, 1]), pos[i], point)
            # one scene for the whole sequence: the same draws of background, light and camera every frame
            frame = subject.render(r, tr, target, k, (w, h), np.random.default_rng([seed, 1]), blink=blink)
            fname = f"{i:05d}.jpg"
            save_image_rgb(part / fname, frame.image)
            row = {
                "frame": i,
                "time_s": round(t, 6),
                "phase": phase,
                "target": name,
                "blink": round(blink, 3),
                **{f"point_{a}_mm": round(float(v), 3) for a, v in zip("xyz", point)},
                **{f"target_{a}": round(float(v), 4) for a, v in zip("xyz", target)},
                "head_yaw_deg": round(float(head[i, 0]), 4),
                "head_pitch_deg": round(float(head[i, 1]), 4),
            }
            rows.append(row)
            labels.append(label_row(fname, "seq", rig, target))
            truth.append({"image": fname, **frame.truth(), "blink": blink, "light": frame.light})
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(TRUTH_COLUMNS), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        with atomic_write(part / "truth.csv") as fh:
            fh.write(buf.getvalue().encode("utf-8"))
        write_labels_csv(part / "labels.csv", labels)
        with atomic_write(part / "simulation.jsonl") as fh:
            fh.write("".join(json.dumps(t) + "\n" for t in truth).encode("utf-8"))
        summary = {
            "output": str(out_dir),
            "frames": n,
            "fps": seq.fps,
            "seconds": seq.seconds,
            "fixations": sum(1 for e in schedule if e[1] == "fixation"),
            "glances": sum(1 for e in schedule if e[1] == "glance"),
            "blinks": len(blinks),
        }
        record = {
            **summary,
            "source_face": source,
            "rig": rig.as_dict(),
            "seed": seed,
            "identity_seed": ident,
            "sequence": asdict(seq),
            "subject_draw": subject.draw.as_dict(),
            "kappa_deg": np.degrees(subject.kappa_rad).tolist(),
        }
        with atomic_write(part / "sequence.json") as fh:
            fh.write(json.dumps(record, indent=1).encode("utf-8"))
    return summary


def read_truth(folder: str | Path, frames: int | None = None) -> list[dict[str, Any]] | None:
    """The rows of a sequence folder's ``truth.csv`` (numbers as floats), or None when it has none.

    Args:
        folder: the sequence folder (``truth.csv`` beside ``sequence.json``).
        frames: the number of frames the folder holds: ``truth.csv`` must have one row for each,
            frames 0, 1, ... in order.

    Raises:
        GazeAugError: an unreadable file, a bad value (naming its line), rows that do not match
            the frames.
    """
    p = Path(folder) / "truth.csv"
    if not (p.is_file() and (Path(folder) / "sequence.json").is_file()):
        return None
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise GazeAugError(f"{p}: not a readable truth file ({exc.__class__.__name__})") from exc
    for line, r in enumerate(rows, start=2):
        try:
            for k in TRUTH_COLUMNS:
                if k not in ("phase", "target"):
                    v = float(r[k])
                    if not math.isfinite(v):
                        raise ValueError(f"{k} is not finite")
                    r[k] = v
            r["frame"] = int(r["frame"])
            if r["phase"] not in ("fixation", "glance", "saccade"):
                raise ValueError(f"unknown phase {r['phase']!r}")
            if r["frame"] != line - 2:
                raise ValueError(f"frame {r['frame']} where frame {line - 2} was expected")
        except (KeyError, TypeError, ValueError) as exc:
            raise GazeAugError(f"{p}, line {line}: expected the columns {list(TRUTH_COLUMNS)} ({exc})") from exc
    if not rows or (frames is not None and len(rows) != frames):
        raise GazeAugError(f"{p}: {len(rows)} rows of truth for {frames if frames is not None else 'some'} frames")
    return rows


def sequence_accuracy(
    track_rows: list[dict[str, Any]],
    selections: list[dict[str, Any]],
    truth: list[dict[str, Any]],
    dwell_s: float,
    late_s: float = 0.25,
    targets: set[str] | None = None,
) -> dict[str, Any]:
    """How well ``gazeaug track`` followed a simulated sequence.

    Args:
        track_rows: the rows of ``gaze.csv`` (as written: strings).
        selections: the selection events (``frame``, ``target``).
        truth: :func:`read_truth`'s rows.
        dwell_s: the dwell time the selections used.
        late_s: a selection of the fixated target up to this long after the fixation ended (the
            gap hysteresis and the smoothing lag) still counts as right.
        targets: the rig's target names: only fixations on them can be selected (a calibration
            pattern's points are no targets); default: every fixated name.

    Returns:
        ``gaze_error_deg`` (median, mean, p90 over the frames with a gaze, during fixations and
        glances; the true direction runs from the tracked gaze origin to the true point),
        ``gaze_error_mm`` (median: the same angle at the point's distance), ``frames_scored``;
        ``fixations`` (on targets long enough to select: longer than ``dwell_s`` plus 0.2 s),
        ``selected_right`` (those during which that target was selected), ``selection_accuracy``
        (the share), ``selections``, ``false_selections`` (a target other than the one fixated, or
        any during a glance or saccade, unless ``late_s`` after fixating it), ``false_per_minute``,
        ``precision``.
    """
    by_frame = {r["frame"]: r for r in truth}
    errs, errs_mm = [], []
    for r in track_rows:
        tr = by_frame.get(int(r["frame"]))
        if tr is None or r.get("status") != "ok" or tr["phase"] == "saccade" or tr["blink"] > 0:
            continue
        g = np.array([float(r["gaze_x"]), float(r["gaze_y"]), float(r["gaze_z"])])
        o = np.array([float(r["origin_x_mm"]), float(r["origin_y_mm"]), float(r["origin_z_mm"])])
        p = np.array([tr["target_x"], tr["target_y"], tr["target_z"]])
        v = p - o
        dist = float(np.linalg.norm(v))
        ang = math.degrees(math.acos(float(np.clip(g @ v / dist, -1.0, 1.0))))
        errs.append(ang)
        errs_mm.append(2 * dist * math.sin(math.radians(ang) / 2))
    # fixations: runs of frames with the same fixated target
    runs: list[tuple[str, int, int]] = []
    for r in truth:
        name = r["target"] if r["phase"] == "fixation" else ""
        if runs and runs[-1][0] == name and runs[-1][2] == r["frame"] - 1:
            runs[-1] = (name, runs[-1][1], r["frame"])
        else:
            runs.append((name, r["frame"], r["frame"]))
    fps = 1.0 / (truth[1]["time_s"] - truth[0]["time_s"]) if len(truth) > 1 else 30.0
    late = int(round(late_s * fps))
    eligible = [
        (n, a, b) for n, a, b in runs if n and (targets is None or n in targets) and (b - a + 1) / fps >= dwell_s + 0.2
    ]
    sel_frames = [(int(e["frame"]), str(e["target"])) for e in selections]
    right = sum(1 for n, a, b in eligible if any(a <= f <= b + late and t == n for f, t in sel_frames))

    def fixated(f: int, t: str) -> bool:
        """Was ``t`` fixated at frame ``f``, or up to ``late`` frames before?"""
        return any(
            by_frame.get(g) is not None and by_frame[g]["phase"] == "fixation" and by_frame[g]["target"] == t
            for g in range(f - late, f + 1)
        )

    false = sum(1 for f, t in sel_frames if not fixated(f, t))
    minutes = len(truth) / fps / 60.0
    e = np.asarray(errs)
    return {
        "frames": len(truth),
        "frames_scored": int(e.size),
        "gaze_error_deg": {
            "median": round(float(np.median(e)), 2) if e.size else None,
            "mean": round(float(e.mean()), 2) if e.size else None,
            "p90": round(float(np.percentile(e, 90)), 2) if e.size else None,
        },
        "gaze_error_mm": {"median": round(float(np.median(errs_mm)), 1) if errs_mm else None},
        "fixations": len(eligible),
        "selected_right": right,
        "selection_accuracy": round(right / len(eligible), 3) if eligible else None,
        "selections": len(sel_frames),
        "false_selections": false,
        "false_per_minute": round(false / minutes, 2) if minutes > 0 else None,
        "precision": round((len(sel_frames) - false) / len(sel_frames), 3) if sel_frames else None,
    }
