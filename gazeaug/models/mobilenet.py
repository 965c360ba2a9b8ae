"""A MobileNetV2-style gaze network in plain PyTorch (inverted residual blocks; no torchvision).

One backbone (shared weights) encodes each 36 x 60 eye patch: a 3 x 3 stride-2 stem,
then inverted residual blocks (1 x 1 expansion, 3 x 3 depthwise, 1 x 1 linear
projection, residual when the shape allows), then global average pooling.
The two eye features and the head pose go through a small MLP to the gaze
(pitch, yaw).
"""

from __future__ import annotations

from typing import Any

from . import import_torch, register_model

__all__ = ["mobilenet_gaze"]

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


def _build(stem: int, blocks: tuple[tuple[int, int, int], ...], hidden: int) -> Any:
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
        def __init__(self) -> None:
            super().__init__()
            layers: list[Any] = [nn.Conv2d(3, stem, 3, 2, 1, bias=False), nn.BatchNorm2d(stem), nn.ReLU6(inplace=True)]
            c = stem
            for e, cout, s in blocks:
                layers.append(InvertedResidual(c, cout, s, e))
                c = cout
            self.features = nn.Sequential(*layers)
            self.out_channels = c

        def forward(self, x: Any) -> Any:
            return self.features(x).mean(dim=(2, 3))

    class MobileNetGaze(nn.Module):  # type: ignore[misc, name-defined]
        """(left (N,3,H,W), right (N,3,H,W), head pose (N,2)) -> gaze (N,2) pitch, yaw radians."""

        def __init__(self) -> None:
            super().__init__()
            self.encoder = EyeEncoder()
            f = self.encoder.out_channels
            self.head = nn.Sequential(nn.Linear(2 * f + 2, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, 2))

        def forward(self, left: Any, right: Any, head_pose: Any) -> Any:
            n = left.shape[0]
            feats = self.encoder(torch.cat([left, right], dim=0))
            return self.head(torch.cat([feats[:n], feats[n:], head_pose], dim=1))

    return MobileNetGaze()


@register_model("mobilenet_gaze")
def mobilenet_gaze(stem: int = 8, hidden: int = 128, blocks: tuple[tuple[int, int, int], ...] = DEFAULT_BLOCKS) -> Any:
    """The default gaze model (see the module docstring); options change its width."""
    return _build(stem, tuple(tuple(b) for b in blocks), hidden)  # type: ignore[misc]
