"""A linear space of face shapes in MediaPipe topology, from the faces behind the built-in model.

The built-in model (:mod:`facemesh.face_models.derive_mediapipe`) is the mean
of about 100 faces (MediaPipe's 3D landmarks on the photos inside pip wheels).
The same faces, each similarity-aligned to the model (Procrustes: rotation,
translation and scale, so size is left out), differ from it by a (468, 3)
residual; the principal components of those residuals span a shape space.
A new shape is ``mean + sum_k c_k std_k component_k`` with ``c_k ~ N(0, 1)``.

Caveat: MediaPipe's depth (z) is a network's guess from one picture and the
LFW crops are 25 x 25 pixels enlarged, so part of the spread is the
detector's noise, not anatomy; the simulator uses the space to draw
*plausible variety*, not to measure people.

Rebuild ``mediapipe468_shapes.npz`` with
``python -m facemesh.face_models.shape_space`` (it reruns MediaPipe on the
same photos as the model's derivation).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["ShapeSpace", "shape_space", "derive_shape_space", "NUM_COMPONENTS"]

#: Components kept (of at most the number of faces - 1).
NUM_COMPONENTS = 12

_FILE = "mediapipe468_shapes.npz"


@dataclass(frozen=True)
class ShapeSpace:
    """A linear shape space over the built-in model's 468 points.

    Attributes:
        mean_mm: (468, 3) float64, mm, head frame: the built-in model's vertices.
        components: (K, 468, 3) float64, unit-norm (over all 1404 numbers), orthogonal.
        std_mm: (K,) float64, mm: the standard deviation of the faces' coefficients along each component.
        sources: (F,) str, the faces it was derived from.
    """

    mean_mm: NDArray[np.float64]
    components: NDArray[np.float64]
    std_mm: NDArray[np.float64]
    sources: NDArray[np.str_]

    @property
    def num_components(self) -> int:
        """K."""
        return int(len(self.std_mm))

    def offset_mm(self, coefficients: NDArray[np.float64]) -> NDArray[np.float64]:
        """(468, 3) float64 mm, head frame: the displacement ``sum_k c_k std_k component_k`` of K coefficients."""
        c = np.asarray(coefficients, dtype=np.float64)
        if c.shape != (self.num_components,):
            raise ValueError(f"shape coefficients: expected shape ({self.num_components},), got {c.shape}")
        return np.tensordot(c * self.std_mm, self.components, axes=1)


@cache
def shape_space() -> ShapeSpace:
    """The shape space shipped with the package (``mediapipe468_shapes.npz``)."""
    with resources.files(__package__).joinpath(_FILE).open("rb") as fh:
        z = np.load(fh, allow_pickle=False)
        return ShapeSpace(
            np.asarray(z["mean_mm"], dtype=np.float64),
            np.asarray(z["components"], dtype=np.float64),
            np.asarray(z["std_mm"], dtype=np.float64),
            np.asarray(z["sources"]),
        )


def derive_shape_space(
    names: list[str], shapes: list[NDArray[np.float64]], mean_mm: NDArray[np.float64], k: int = NUM_COMPONENTS
) -> ShapeSpace:
    """Principal components of the faces' residuals to ``mean_mm`` after similarity alignment.

    Args:
        names: one per face.
        shapes: per face, (>= 468, 3) float MediaPipe landmarks as ``(x_px, y_px, z * W)``.
        mean_mm: (468, 3) float, mm, head frame: the model the faces are aligned to.
        k: components kept.
    """
    from ..geometry import apply_similarity, similarity_transform

    mean = np.asarray(mean_mm, dtype=np.float64)
    n = len(mean)
    res = []
    for s in shapes:
        pts = np.asarray(s, dtype=np.float64)[:n]
        res.append(apply_similarity(pts, *similarity_transform(pts, mean)) - mean)
    x = np.stack(res).reshape(len(res), -1)
    x -= x.mean(axis=0)
    _, sv, vt = np.linalg.svd(x, full_matrices=False)
    k = min(k, len(sv))
    comps = vt[:k].reshape(k, n, 3)
    # a deterministic sign per component: its largest entry positive
    for i in range(k):
        flat = comps[i].reshape(-1)
        if flat[np.argmax(np.abs(flat))] < 0:
            comps[i] = -comps[i]
    std = sv[:k] / np.sqrt(max(1, len(res) - 1))
    return ShapeSpace(mean, comps, std, np.array(names))


def main(argv: list[str] | None = None) -> None:
    """Command-line entry: write ``mediapipe468_shapes.npz``."""
    from ..io import atomic_write
    from . import builtin_face_model
    from .derive_mediapipe import derivation_inputs

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=Path(__file__).with_name(_FILE))
    args = parser.parse_args(argv)
    names, shapes, _ = derivation_inputs()
    space = derive_shape_space(names, shapes, builtin_face_model("mediapipe").vertices_mm)
    with atomic_write(args.output) as fh:
        np.savez_compressed(
            fh,
            mean_mm=space.mean_mm,
            components=space.components.astype(np.float32),
            std_mm=space.std_mm,
            sources=space.sources,
        )
    print(
        f"wrote {args.output}: {space.num_components} components, std "
        + ", ".join(f"{v:.2f}" for v in space.std_mm)
        + " mm"
    )


if __name__ == "__main__":
    main()
