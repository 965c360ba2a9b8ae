"""Benchmarks that print figures (``gazeaug bench render``); not timed unit tests."""

from __future__ import annotations

import platform
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from .augment import FaceAsset, render_poses, sampled_placement
from .normalize import NormalizationSettings
from .render import create_renderer
from .sampling import HeadPoseDistribution

__all__ = ["bench_render"]


def bench_render(
    assets: Sequence[FaceAsset],
    *,
    renderer: str = "raycast",
    n: int = 2000,
    per_face: int = 16,
    batch: int = 16,
    seed: int = 0,
    settings: NormalizationSettings | None = None,
) -> dict[str, Any]:
    """Eye patches per second for ``n`` samples (two patches each).

    A new face scene is built every ``per_face`` samples, cycling through
    ``assets`` (so scene building and texture upload count as a dataset brings
    new faces); poses come from the default head-pose distribution, rendered
    ``batch`` samples per call. Mesh building (landmarks, PnP) is not included.

    Returns:
        A JSON-serialisable dict: renderer, samples, patches, seconds,
        patches_per_second, per_face, faces_loaded, patch_size, cpu_count.
    """
    import os

    s = settings or NormalizationSettings()
    rend = create_renderer(renderer, settings=s)
    poses = HeadPoseDistribution().sample(n, seed)
    done = 0
    faces = 0
    # warm-up (driver start, first shader compile) is not timed
    warm = rend.scene(assets[0].render_mesh)
    render_poses(warm, assets[0], [sampled_placement(assets[0], 0.0, 0.5)], settings=s, renderer_name=renderer)
    del warm
    t0 = time.perf_counter()
    while done < n:
        asset = assets[faces % len(assets)]
        scene = rend.scene(asset.render_mesh)
        faces += 1
        todo = min(per_face, n - done)
        for a in range(0, todo, batch):
            yp = poses[done + a : done + min(todo, a + batch)]
            render_poses(
                scene,
                asset,
                [sampled_placement(asset, y, p) for y, p in yp],
                gaze_vector=np.array([0.0, 0.0, -1.0]),
                settings=s,
                renderer_name=renderer,
            )
        done += todo
        close = getattr(scene, "close", None)
        if close is not None:
            close()
    dt = time.perf_counter() - t0
    return {
        "renderer": renderer,
        "samples": n,
        "patches": 2 * n,
        "seconds": round(dt, 3),
        "patches_per_second": round(2 * n / dt, 1),
        "per_face": per_face,
        "faces_loaded": faces,
        "patch_size": list(s.patch_size_wh),
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
    }
