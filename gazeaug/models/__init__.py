"""Gaze models built by name: ``create_model("mobilenet_gaze")``; other architectures register themselves.

Every model takes the two normalized eye patches and the normalized head pose
and predicts the gaze (pitch, yaw) in the face-centre normalized frame (the
``gaze`` of the HDF5 training sets). Inputs are prepared by
:func:`gazeaug.models.preprocess.prepare_inputs`, used by training and inference alike.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ..errors import GazeAugError

__all__ = ["register_model", "create_model", "MODELS", "TORCH_INSTALL_HINT", "import_torch"]

TORCH_INSTALL_HINT = "the gaze model needs PyTorch: pip install torch==2.13.0 (or pip install 'gazeaug[train]')"

#: name -> factory(**options) returning a torch.nn.Module.
MODELS: dict[str, Callable[..., Any]] = {}


def import_torch() -> Any:
    """Import torch or raise ImportError with an install hint."""
    try:
        import torch  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError(f"{TORCH_INSTALL_HINT} ({exc})") from exc
    return torch


def register_model(name: str) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorator: make a model factory available to :func:`create_model` under ``name``."""

    def deco(factory: Callable[..., Any]) -> Callable[..., Any]:
        MODELS[name] = factory
        return factory

    return deco


def create_model(name: str = "mobilenet_gaze", **options: Any) -> Any:
    """Build a registered model (``torch.nn.Module``) by name."""
    from . import mobilenet  # noqa: F401 - registers the built-in models

    if name not in MODELS:
        raise GazeAugError(f"model: expected one of {sorted(MODELS)}, got {name!r}")
    return MODELS[name](**options)
