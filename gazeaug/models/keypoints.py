"""A training-only keypoint head: the eye encoder taught to find the iris and the eye opening.

``gazeaug train --keypoint-loss W`` (:attr:`gazeaug.train.TrainSettings.keypoint_loss_weight`)
attaches a small head to the eye encoder's last feature map of stride 4 (9 x 15 cells for a
60 x 36 patch): a 3 x 3 convolution, a ReLU, a 1 x 1 convolution to one heat map per point,
and a soft-argmax that turns each map into a position in the patch. The training loss adds
``W`` times the mean absolute error of those positions, in units of 10 px, against the
``eye_keypoints`` the training set records (:data:`gazeaug.normalize.EYE_KEYPOINTS`: the iris
centre and the eye opening's centre of each drawn eye). The gaze network itself is unchanged:
the head reads a forward hook's copy of the map, the model file keeps the gaze network alone,
and prediction costs nothing more. What it buys is measured in docs/model.md ("the keypoint
head as a loss").

Convention: positions are (u, v) px in the eye patch, pixel centres at whole numbers, x right,
y down (:meth:`gazeaug.camera.NormalizedCamera.project`); a map cell's position is its centre,
``(j + 0.5) * W / w - 0.5`` for column ``j`` of ``w`` over a patch ``W`` wide. (What a cell sees
is centred elsewhere: two 3 x 3 convolutions of stride 2 and padding 1 centre cell ``j``'s
receptive field on input pixel ``4 j``, 1.5 px before its label. The head's own 3 x 3
convolution learns that shift; the measured runs used these labels.)
"""

from __future__ import annotations

from typing import Any

from ..errors import GazeAugError
from . import import_torch

__all__ = ["attach_keypoint_head", "keypoint_loss", "KEYPOINT_SCALE_PX"]

#: The loss's unit: the mean absolute error of the positions is divided by it.
KEYPOINT_SCALE_PX = 10.0


def attach_keypoint_head(model: Any, patch_size_wh: tuple[int, int], points: int = 2) -> tuple[Any, Any]:
    """A keypoint head on ``model``'s eye encoder, fed by a forward hook.

    Args:
        model: a gaze model with an eye encoder ``model.encoder.features`` (an ``nn.Sequential``
            run on the left and right patches stacked), e.g. ``mobilenet_gaze``.
        patch_size_wh: the eye patches' (width, height), px.
        points: heat maps, one per point (default 2: :data:`gazeaug.normalize.EYE_KEYPOINTS`).

    Returns:
        ``(head, handle)``: ``head()`` gives the points of the model's last forward pass,
        float32 (2B, points, 2) px (the B left eyes, then the B right ones, as the encoder
        stacks them); ``handle.remove()`` detaches the hook. The head is on the model's device.

    Raises:
        GazeAugError: the model has no such encoder, or none of its layers keeps a stride of 4 or less.
    """
    torch = import_torch()
    nn = torch.nn
    features = getattr(getattr(model, "encoder", None), "features", None)
    if not isinstance(features, nn.Sequential):
        raise GazeAugError(
            f"keypoint head: expected a model with an eye encoder (model.encoder.features), got {type(model).__name__}"
        )
    w, h = int(patch_size_wh[0]), int(patch_size_wh[1])
    param = next(model.parameters())
    shapes: list[tuple[int, int, int]] = []
    hooks = [layer.register_forward_hook(lambda _m, _i, o: shapes.append(tuple(o.shape[1:]))) for layer in features]
    was_training = model.training
    try:  # one dry pass (evaluation mode: the batch-norm statistics stay as they are) for the maps' shapes
        model.eval()
        with torch.no_grad():
            features(torch.zeros((1, 3, h, w), dtype=param.dtype, device=param.device))
    finally:
        for hk in hooks:
            hk.remove()
        model.train(was_training)
    taps = [i for i, (_, mh, mw) in enumerate(shapes) if 4 * mh >= h and 4 * mw >= w]
    if not taps:
        raise GazeAugError(f"keypoint head: no layer of the eye encoder keeps a stride <= 4 (maps {shapes})")
    tap = taps[-1]
    channels, mh, mw = shapes[tap]

    class KeypointHead(nn.Module):  # type: ignore[misc, name-defined]
        def __init__(self) -> None:
            super().__init__()
            self.net = nn.Sequential(
                nn.Conv2d(channels, channels, 3, 1, 1), nn.ReLU(inplace=True), nn.Conv2d(channels, points, 1)
            )
            self.register_buffer("us", (torch.arange(mw, dtype=torch.float32) + 0.5) * (w / mw) - 0.5)
            self.register_buffer("vs", (torch.arange(mh, dtype=torch.float32) + 0.5) * (h / mh) - 0.5)
            self.feature_map: Any = None

        def forward(self) -> Any:
            if self.feature_map is None:
                raise GazeAugError("keypoint head: run the model first (the head reads its eye encoder's map)")
            maps = self.net(self.feature_map).float()  # (2B, points, mh, mw)
            p = torch.softmax(maps.flatten(2), dim=-1).view_as(maps)
            u = (p.sum(2) * self.us).sum(-1)
            v = (p.sum(3) * self.vs).sum(-1)
            return torch.stack([u, v], dim=-1)

    head = KeypointHead().to(param.device)

    def keep(_m: Any, _i: Any, out: Any) -> None:
        head.feature_map = out

    return head, features[tap].register_forward_hook(keep)


def keypoint_loss(predicted: Any, target: Any) -> Any:
    """Mean absolute error of the known coordinates, in units of :data:`KEYPOINT_SCALE_PX`.

    The mean runs over the known (u, v) values of the batch: a batch with few known rows weighs as
    much as one with many (a step's loss, not a row's).

    Args:
        predicted: float32 (..., 2) px.
        target: float32 (..., 2) px, the same shape; NaN where unknown (such points are left out).

    Returns:
        A scalar tensor; 0 (still connected to ``predicted``) when no point is known.
    """
    known = ~target.isnan()
    if predicted.shape != target.shape:
        raise GazeAugError(
            f"keypoints: expected predictions of shape {tuple(target.shape)}, got {tuple(predicted.shape)}"
        )
    diff = (predicted - target.nan_to_num()).abs() * known
    return diff.sum() / known.sum().clamp(min=1) / KEYPOINT_SCALE_PX
