"""A MobileNetV2-style gaze network in plain PyTorch (inverted residual blocks; no torchvision).

One backbone (shared weights) encodes each 36 x 60 eye patch: a 3 x 3 stride-2 stem,
then inverted residual blocks (1 x 1 expansion, 3 x 3 depthwise, 1 x 1 linear
projection, residual when the shape allows), then global average pooling.
The two eye features and the head pose go through a small MLP to the gaze
(pitch, yaw).

With ``face=True`` the model also reads the normalized face patch
(``--face-patch``, :func:`gazeaug.normalize.face_patch_camera`): a second
encoder of its own weights (:data:`FACE_BLOCKS`) reads it average-pooled by
``face_pool`` (224 x 224 -> 112 x 112 by default), and its features join the
eyes' and the head pose's before the MLP. Such a model's ``forward`` takes the
face patch as a fourth input and its ``uses_face`` attribute is True
(:func:`gazeaug.models.uses_face`).
"""

from __future__ import annotations

from typing import Any

from ..errors import GazeAugError
from . import import_torch, register_model

__all__ = ["mobilenet_gaze", "mobilenet_gaze_wide"]

#: (expansion, out channels, stride) per inverted residual block, after a stride-2 stem:
#: 36 x 60 -> 18 x 30 -> 9 x 15 -> 5 x 8 -> 5 x 8 -> 3 x 4. Sized for CPU training
#: (about 2000 samples per second on 2 cores; see docs/benchmarks.md).
DEFAULT_BLOCKS: tuple[tuple[int, int, int], ...] = (
    (1, 8, 1),
    (3, 16, 2),
    (3, 24, 2),
    (3, 32, 1),
    (3, 48, 2),
)


#: The wide variant's eye-encoder blocks (:func:`mobilenet_gaze_wide`): twice the channels and
#: expansion 4, one more stride-1 block's worth of depth at 9 x 15; with a 16-channel stem and a
#: 256-wide MLP, 81k weights against the default's 31k.
WIDE_BLOCKS: tuple[tuple[int, int, int], ...] = (
    (1, 16, 1),
    (4, 24, 2),
    (4, 32, 2),
    (4, 48, 1),
    (4, 64, 2),
)

#: The face encoder's blocks, after its stride-2 stem, on the face patch pooled by ``face_pool``:
#: 112 x 112 -> 56 -> 56 -> 28 -> 14 -> 7 -> 4 (a 224 x 224 patch pooled by 2).
FACE_BLOCKS: tuple[tuple[int, int, int], ...] = (
    (1, 8, 1),
    (3, 16, 2),
    (3, 24, 2),
    (3, 32, 2),
    (3, 48, 2),
)


def _build(
    stem: int, blocks: tuple[tuple[int, int, int], ...], hidden: int, face: bool = False, face_pool: int = 2
) -> Any:
    torch = import_torch()
    nn = torch.nn

    class InvertedResidual(nn.Module):  # type: ignore[misc, name-defined]
        def __init__(self, cin: int, cout: int, stride: int, expansion: int):
            super().__init__()
            mid = cin * expansion
            layers: list[Any] = []
            if expansion != 1:
                layers += [nn.Conv2d(cin, mid, 1, bias=False), nn.BatchNorm2d(mid), nn.ReLU6(inplace=True)]
            layers += [
                nn.Conv2d(mid, mid, 3, stride, 1, groups=mid, bias=False),
                nn.BatchNorm2d(mid),
                nn.ReLU6(inplace=True),
                nn.Conv2d(mid, cout, 1, bias=False),
                nn.BatchNorm2d(cout),
            ]
            self.body = nn.Sequential(*layers)
            self.residual = stride == 1 and cin == cout

        def forward(self, x: Any) -> Any:
            y = self.body(x)
            return x + y if self.residual else y

    class EyeEncoder(nn.Module):  # type: ignore[misc, name-defined]
        def __init__(self, block_list: tuple[tuple[int, int, int], ...] = blocks, pool: int = 1) -> None:
            super().__init__()
            layers: list[Any] = [nn.AvgPool2d(pool)] if pool > 1 else []
            layers += [nn.Conv2d(3, stem, 3, 2, 1, bias=False), nn.BatchNorm2d(stem), nn.ReLU6(inplace=True)]
            c = stem
            for e, cout, s in block_list:
                layers.append(InvertedResidual(c, cout, s, e))
                c = cout
            self.features = nn.Sequential(*layers)
            self.out_channels = c

        def forward(self, x: Any) -> Any:
            return self.features(x).mean(dim=(2, 3))

    class MobileNetGaze(nn.Module):  # type: ignore[misc, name-defined]
        """(left (N,3,H,W), right (N,3,H,W), head pose (N,2)[, face (N,3,Hf,Wf)]) -> gaze (N,2) pitch, yaw radians."""

        def __init__(self) -> None:
            super().__init__()
            self.uses_face = bool(face)
            self.encoder = EyeEncoder()
            f = 2 * self.encoder.out_channels
            if self.uses_face:
                self.face_encoder = EyeEncoder(FACE_BLOCKS, face_pool)
                f += self.face_encoder.out_channels
            self.head = nn.Sequential(nn.Linear(f + 2, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, 2))

        def forward(self, left: Any, right: Any, head_pose: Any, face: Any = None) -> Any:
            n = left.shape[0]
            feats = self.encoder(torch.cat([left, right], dim=0))
            parts = [feats[:n], feats[n:], head_pose]
            if self.uses_face:
                if face is None:
                    raise GazeAugError("this model reads a face patch as well: give it as the fourth input")
                parts.append(self.face_encoder(face))
            return self.head(torch.cat(parts, dim=1))

    return MobileNetGaze()


@register_model("mobilenet_gaze")
def mobilenet_gaze(
    stem: int = 8,
    hidden: int = 128,
    blocks: tuple[tuple[int, int, int], ...] = DEFAULT_BLOCKS,
    face: bool = False,
    face_pool: int = 2,
) -> Any:
    """The default gaze model (see the module docstring); options change its width.

    Args:
        stem: channels of the stem (both encoders).
        hidden: width of the MLP.
        blocks: (expansion, out channels, stride) of the eye encoder's blocks.
        face: also read the normalized face patch (default False: the eyes and the head pose).
        face_pool: the face patch is average-pooled by this factor first (default 2: 224 -> 112).

    Raises:
        GazeAugError: ``face`` not a bool, or ``face_pool`` not an integer from 1 to 8.
    """
    if not isinstance(face, bool):
        raise GazeAugError(f"mobilenet_gaze face: expected true or false, got {face!r}")
    if not (isinstance(face_pool, int) and not isinstance(face_pool, bool) and 1 <= face_pool <= 8):
        raise GazeAugError(f"mobilenet_gaze face_pool: expected an integer from 1 to 8, got {face_pool!r}")
    return _build(stem, tuple(tuple(b) for b in blocks), hidden, face, face_pool)  # type: ignore[misc]


@register_model("mobilenet_gaze_wide")
def mobilenet_gaze_wide(
    stem: int = 16,
    hidden: int = 256,
    blocks: tuple[tuple[int, int, int], ...] = WIDE_BLOCKS,
    face: bool = False,
    face_pool: int = 2,
) -> Any:
    """:func:`mobilenet_gaze` 2.6 x wider (81k weights): better on large augmented sets, 1.3 x the CPU time.

    Measured on issue 13's wheelchair test (9 new people, the training sets made with
    ``augment --with-source``): 7.97 deg mean over three draws against the default's 8.56, and
    better on each draw; on the sets without the original rows it was not better
    (docs/model.md, "Measured: a wider network on the with-source sets"). The same options as
    :func:`mobilenet_gaze`, with these defaults.
    """
    return mobilenet_gaze(stem=stem, hidden=hidden, blocks=blocks, face=face, face_pool=face_pool)
