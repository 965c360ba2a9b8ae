"""Gaze models built by name: ``create_model("mobilenet_gaze")``; other architectures register themselves.

The registry :data:`MODELS` (a :class:`gazeaug.registry.Registry`, the style
renderers and dataset readers share) maps a name to its factory, or to
``"package.module:factory"`` imported on first use, so listing the names needs
no PyTorch.

Every model takes the two normalized eye patches and the normalized head pose
and predicts the gaze (pitch, yaw) in the face-centre normalized frame (the
``gaze`` of the HDF5 training sets). Inputs are prepared by
:func:`gazeaug.models.preprocess.prepare_inputs`, used by training and inference alike.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from typing import Any

from ..errors import GazeAugError
from ..registry import Registry, Target

__all__ = [
    "register_model",
    "create_model",
    "uses_face",
    "MODELS",
    "TORCH_INSTALL_HINT",
    "import_torch",
    "one_torch_thread",
]

TORCH_INSTALL_HINT = "the gaze model needs PyTorch: pip install torch==2.13.0 (or pip install 'gazeaug[train]')"

#: name -> factory(**options) returning a torch.nn.Module (imported when first used).
MODELS = Registry("model", GazeAugError)
MODELS.register("mobilenet_gaze", "gazeaug.models.mobilenet:mobilenet_gaze")
MODELS.register("mobilenet_gaze_wide", "gazeaug.models.mobilenet:mobilenet_gaze_wide")


def import_torch() -> Any:
    """Import torch or raise ImportError with an install hint."""
    try:
        import torch  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError(f"{TORCH_INSTALL_HINT} ({exc})") from exc
    return torch


@contextlib.contextmanager
def one_torch_thread() -> Iterator[None]:
    """PyTorch on one CPU thread inside the block, then as it was (nothing to do where it is not loaded).

    For inference one sample at a time (``evaluate``, ``track``): a small network on one sample
    runs fastest on one thread (1.1 ms against 3.2 ms with two threads competing with
    MediaPipe's, measured by ``track``), and its floats then do not depend on the machine's
    thread count: a PyTorch CPU kernel may split its sums by thread, so this machine and a Ray
    actor (one thread each) give the same rows, bit for bit, only on the same count.
    """
    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    before = int(torch.get_num_threads())
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def register_model(name: str, target: Target | None = None) -> Any:
    """Make a model factory available to :func:`create_model` under ``name``.

    Use as a decorator (``@register_model("name")``), or give ``target``: the factory or
    ``"package.module:factory"`` (imported when the model is first created).
    """
    return MODELS.register(name, target)


def uses_face(model: Any) -> bool:
    """True when ``model`` reads the normalized face patch as a fourth input (``mobilenet_gaze(face=True)``)."""
    return bool(getattr(model, "uses_face", False))


def create_model(name: str = "mobilenet_gaze", **options: Any) -> Any:
    """Build a registered model (``torch.nn.Module``) by name.

    Raises:
        GazeAugError: an unknown name (the message lists the registered ones).
    """
    return MODELS.create(name, **options)
