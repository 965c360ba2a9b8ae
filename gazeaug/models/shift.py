"""Shift averaging: a model's prediction averaged over its eye patches translated by a few pixels.

The training translates every eye patch by up to ``TrainAugment.shift_px`` pixels (10 by
default), so a model answers for a patch framed a little off as well as for the patch itself,
each answer with its own error. :func:`shift_averaged` returns a module that runs the model on
the patches and on 8 translations of them, by ``px`` pixels along each axis and both diagonals
(both eyes together, one batch of 9N), and averages the 9 (pitch, yaw) answers: a translation
does not move the gaze, so the average keeps the answer and thins out the error.

Measured (2026-11-28, issue 13's benchmark, 10 models of earlier runs evaluated by ``gazeaug
evaluate`` on their test sets, 9 new people x 15 in the wheelchair rig; docs/model.md): 3 px
lowered the mean error by 0.34 deg on average (9.70 -> 9.37; from -0.06 to +0.98, 7 of 10 by
more than 0.05 deg), r pitch 0.66 -> 0.67 and yaw 0.88 -> 0.89. It costs 9 x the network's
rows per prediction, about 2-4 x its time for one frame (a batch of 18 rows costs less than 9
batches of 2; docs/model.md, docs/tracking.md).

A model file records it (``prediction.shift_average_px``, set by
:attr:`gazeaug.train.TrainSettings.shift_average_px`), and :func:`gazeaug.train.load_model`
wraps the network accordingly, so ``predict``, ``evaluate``, ``track``, the estimator and the
ONNX export all predict the same way.
"""

from __future__ import annotations

from typing import Any

from ..errors import GazeAugError
from . import import_torch

__all__ = ["shift_averaged", "shift_offsets", "shift_average_px_of", "MAX_SHIFT_AVERAGE_PX"]

#: The largest translation shift averaging takes, pixels (the training translates by up to 16).
MAX_SHIFT_AVERAGE_PX = 8


def shift_offsets(px: int) -> tuple[tuple[int, int], ...]:
    """The 9 translations (down, right), pixels, that :func:`shift_averaged` averages: ``{-px, 0, px}`` squared.

    ``(0, 0)`` first; ``()`` for ``px`` 0 (no averaging).
    """
    if px == 0:
        return ()
    return ((0, 0), *((dy, dx) for dy in (-px, 0, px) for dx in (-px, 0, px) if (dy, dx) != (0, 0)))


def shift_average_px_of(model: Any) -> int:
    """The translation ``model`` averages over, pixels (0: none), found through wrappers' ``net``."""
    while model is not None:
        px = getattr(model, "shift_average_px", None)
        if isinstance(px, int) and not isinstance(px, bool):
            return px
        model = getattr(model, "net", None)
    return 0


def shift_averaged(model: Any, px: int) -> Any:
    """``model`` (a ``torch.nn.Module`` taking (left, right, head pose)) with shift-averaged predictions.

    The returned module takes and returns what ``model`` does: left and right eye patches,
    float32 (N, C, H, W) as :func:`gazeaug.models.preprocess.prepare_inputs` gives them (H and
    W greater than ``px``); the head pose, float32 (N, 2) radians (pitch, yaw), face-centre
    normalized frame; and returns the gaze (N, 2) in the same units and frame: the mean of
    ``model(T l, T r, h)`` over the 9 translations ``T`` of :func:`shift_offsets` (content moved
    ``dy`` rows down and ``dx`` columns right; the edge filled by reflection, as the training's
    translations fill it). A model that reads the face patch (:func:`gazeaug.models.uses_face`)
    takes it fourth and is given it untranslated. The wrapped network is its ``net`` attribute
    (``state_dict`` keys prefixed ``net.``). ``px`` 0: ``model`` itself, unwrapped.

    Convention: translations are in the patch's pixel grid, rows down, columns right; the same
    offset is applied to both eyes.

    Raises:
        GazeAugError: ``px`` not an integer from 0 to :data:`MAX_SHIFT_AVERAGE_PX`.
    """
    torch = import_torch()
    if not (isinstance(px, int) and not isinstance(px, bool) and 0 <= px <= MAX_SHIFT_AVERAGE_PX):
        raise GazeAugError(f"shift_average_px: expected an integer from 0 to {MAX_SHIFT_AVERAGE_PX}, got {px!r}")
    if px == 0:
        return model
    offsets = shift_offsets(px)

    class ShiftAveraged(torch.nn.Module):  # type: ignore[misc, name-defined]
        #: read by :func:`gazeaug.export.export_onnx`: the module itself averages
        shift_average_px = px

        def __init__(self, net: Any) -> None:
            super().__init__()
            self.net = net
            self.uses_face = bool(getattr(net, "uses_face", False))

        def _translated(self, x: Any) -> Any:
            """(9N, C, H, W): ``x`` (N, C, H, W) under each of the 9 translations, offset by offset."""
            h, w = int(x.shape[-2]), int(x.shape[-1])
            padded = torch.nn.functional.pad(x, (px, px, px, px), mode="reflect")
            # content moved dy down reads the padded rows from px - dy
            return torch.cat([padded[..., px - dy : px - dy + h, px - dx : px - dx + w] for dy, dx in offsets])

        def forward(self, left: Any, right: Any, head: Any, face: Any = None) -> Any:
            n, k = left.shape[0], len(offsets)
            fast = torch.channels_last if left.dim() == 4 else torch.contiguous_format
            inputs = [
                self._translated(left).contiguous(memory_format=fast),
                self._translated(right).contiguous(memory_format=fast),
                head.repeat(k, 1),
            ]
            if face is not None:
                inputs.append(face.repeat(k, 1, 1, 1).contiguous(memory_format=fast))
            out = self.net(*inputs)
            # the 9 answers summed slice by slice (a reshape to (9, N, 2) exports to an ONNX Reshape
            # that reads N = 0 as "copy this dimension", so an empty batch would fail there)
            total = out[:n]
            for i in range(1, k):
                total = total + out[i * n : (i + 1) * n]
            return total / k

    return ShiftAveraged(model)
