"""Benchmarks that print figures (``gazeaug bench render``); not timed unit tests."""

from __future__ import annotations

import platform
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from .augment import FaceAsset, render_poses, sampled_placements
from .normalize import NormalizationSettings
from .render import create_renderer
from .sampling import HeadPoseDistribution

__all__ = ["bench_render"]


def _render_chunk(
    assets: Sequence[FaceAsset],
    renderer: str,
    poses: np.ndarray,
    per_face: int,
    batch: int,
    settings: NormalizationSettings,
    first_face: int,
    threads: int = 0,
) -> int:
    """Render ``poses`` (K, 2) cycling through faces; returns how many faces were loaded."""
    rend = create_renderer(renderer, settings=settings, **({"threads": threads} if renderer == "raycast" else {}))
    done, faces = 0, 0
    while done < len(poses):
        asset = assets[(first_face + faces) % len(assets)]
        scene = rend.scene(asset.render_mesh)
        faces += 1
        todo = min(per_face, len(poses) - done)
        for a in range(0, todo, batch):
            yp = poses[done + a : done + min(todo, a + batch)]
            render_poses(
                scene,
                asset,
                sampled_placements(asset, yp),
                gaze_vector=np.array([0.0, 0.0, -1.0]),
                settings=settings,
                renderer_name=renderer,
            )
        done += todo
        close = getattr(scene, "close", None)
        if close is not None:
            close()
    return faces


def _warm(assets: Sequence[FaceAsset], renderer: str, settings: NormalizationSettings) -> int:
    """Start the renderer (driver, shader compilation, imports) outside the timed part."""
    return _render_chunk(assets[:1], renderer, np.array([[0.0, 0.5]]), 1, 1, settings, 0)


def bench_render(
    assets: Sequence[FaceAsset],
    *,
    renderer: str = "raycast",
    n: int = 2000,
    per_face: int = 16,
    batch: int = 16,
    seed: int = 0,
    workers: int = 1,
    settings: NormalizationSettings | None = None,
) -> dict[str, Any]:
    """Eye patches per second for ``n`` samples (two patches each).

    A new face scene is built every ``per_face`` samples, cycling through
    ``assets`` (so scene building and texture upload count as a dataset brings
    new faces); poses come from the default head-pose distribution, rendered
    ``batch`` samples per call, split over ``workers`` processes (each casting
    with one Embree thread when there are several). Mesh building
    (landmarks, PnP) and process start-up are not included.

    Returns:
        A JSON-serialisable dict: renderer, samples, patches, seconds,
        patches_per_second, per_face, faces_loaded, workers, patch_size, cpu_count.
    """
    import os

    s = settings or NormalizationSettings()
    poses = HeadPoseDistribution().sample(n, seed)
    chunks = [c for c in np.array_split(poses, max(1, int(workers))) if len(c)]
    if len(chunks) <= 1:
        _warm(assets, renderer, s)
        t0 = time.perf_counter()
        faces = _render_chunk(assets, renderer, poses, per_face, batch, s, 0)
        dt = time.perf_counter() - t0
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(len(chunks), mp_context=mp.get_context("spawn")) as pool:
            list(pool.map(_warm, [assets] * len(chunks), [renderer] * len(chunks), [s] * len(chunks)))
            t0 = time.perf_counter()
            futures = [
                pool.submit(_render_chunk, assets, renderer, c, per_face, batch, s, i, 1) for i, c in enumerate(chunks)
            ]
            faces = sum(f.result() for f in futures)
            dt = time.perf_counter() - t0
    return {
        "renderer": renderer,
        "samples": n,
        "patches": 2 * n,
        "seconds": round(dt, 3),
        "patches_per_second": round(2 * n / dt, 1),
        "per_face": per_face,
        "faces_loaded": faces,
        "workers": len(chunks),
        "patch_size": list(s.patch_size_wh),
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
    }
