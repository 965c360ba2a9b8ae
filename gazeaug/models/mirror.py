"""Mirror averaging: a model's prediction averaged with its prediction on the mirrored face.

A face seen in a left-right mirror is another plausible face: its left eye patch is
the original right patch mirrored about the normalized camera's principal point
(:func:`facemesh.conventions.mirrored_columns`), its right patch the mirrored left
one, and its head pose and gaze have their yaw negated
(:data:`facemesh.conventions.MIRROR_PITCHYAW`). A model trained on faces of both
handednesses answers both; :func:`mirror_averaged` returns a module that runs the
model on the face and on its mirror image (one batch of 2N) and averages the two
(pitch, yaw) answers, the mirrored one mapped back by negating its yaw.

Measured (issue 13's protocol, 9 x 40, wheelchair rig, 3 seeds; docs/simulation.md):
the augmented model's error on new people fell from 12.0 to 11.1 deg, in every seed.
The training is unchanged; a model file records whether its predictions average
(``prediction.mirror_average``, set by :attr:`gazeaug.train.TrainSettings.mirror_average`),
and :func:`gazeaug.train.load_model` wraps the network accordingly, so ``predict``,
``evaluate``, ``track``, the estimator and the ONNX export all predict the same way.
"""

from __future__ import annotations

from typing import Any

from . import import_torch

__all__ = ["mirror_averaged"]


def mirror_averaged(model: Any) -> Any:
    """``model`` (a ``torch.nn.Module`` taking (left, right, head pose)) with mirror-averaged predictions.

    The returned module takes and returns what ``model`` does: left and right eye
    patches, float32 (N, C, H, W) as :func:`gazeaug.models.preprocess.prepare_inputs`
    gives them (any C, any H and W >= 2); the head pose, float32 (N, 2) radians
    (pitch, yaw), face-centre normalized frame; and returns the gaze (N, 2) in the same
    units and frame: ``(model(l, r, h) + m(model(M r, M l, m h))) / 2``, where ``M``
    mirrors a patch's columns and ``m`` negates a yaw. A model that reads the face patch
    (:func:`gazeaug.models.uses_face`) takes it fourth, float32 (N, C, Hf, Wf), and is given
    ``M f``. The wrapped network is its ``net`` attribute (its weights, ``state_dict`` keys prefixed ``net.``).
    """
    torch = import_torch()
    from facemesh.conventions import MIRROR_PITCHYAW, mirrored_columns

    class MirrorAveraged(torch.nn.Module):  # type: ignore[misc, name-defined]
        #: read by :func:`gazeaug.export.export_onnx`: the module itself averages
        mirror_average = True

        def __init__(self, net: Any) -> None:
            super().__init__()
            self.net = net
            self.uses_face = bool(getattr(net, "uses_face", False))
            self.register_buffer("sign", torch.as_tensor(MIRROR_PITCHYAW, dtype=torch.float32), persistent=False)
            self._cols: dict[tuple[int, str], Any] = {}  # mirrored column indices per (width, device)

        def _columns(self, x: Any) -> Any:
            key = (int(x.shape[-1]), str(x.device))
            if key not in self._cols:
                self._cols[key] = torch.as_tensor(mirrored_columns(key[0]), device=x.device)
            return self._cols[key]

        def forward(self, left: Any, right: Any, head: Any, face: Any = None) -> Any:
            n = left.shape[0]
            cols = self._columns(left)
            sign = self.sign.to(head.dtype)
            # channels last, as prepare_inputs gives them: the network runs about twice as fast on it
            fast = torch.channels_last if left.dim() == 4 else torch.contiguous_format
            inputs = [
                torch.cat([left, right.index_select(-1, cols)]).contiguous(memory_format=fast),
                torch.cat([right, left.index_select(-1, cols)]).contiguous(memory_format=fast),
                torch.cat([head, head * sign]),
            ]
            if face is not None:  # the face mirrored about its own principal point
                inputs.append(
                    torch.cat([face, face.index_select(-1, self._columns(face))]).contiguous(memory_format=fast)
                )
            both = self.net(*inputs)
            return (both[:n] + both[n:] * sign.to(both.dtype)) / 2

    return MirrorAveraged(model)
