"""Training-time augmentation of eye patches, on the model's device (a GPU when there is one).

Models trained on simulated eye patches learn the identities' look (skin tone,
exposure, sharpness) along with the gaze. :class:`TrainAugment` perturbs every
training patch, per sample and at random, in ways that keep the gaze label:

==============  =========================================================  ==============
what            how (per patch, drawn uniformly unless said)               default
==============  =========================================================  ==============
zoom            about the normalized camera's principal point, factor in    0 (off)
                ``[1 - scale, 1 + scale]`` (the same camera with that
                times the focal length: labels unchanged), bilinear,
                borders reflected; first of the patches' operations
translation     whole pixels in ``[-shift_px, shift_px]`` per axis,         10 px
                borders reflected (as a pad-reflect and a random crop)
blur            Gaussian, sigma in ``[0, blur_sigma]`` px; applied with     1.2 px
                the translation as one separable, shifted kernel
colour gain     one gain per channel in ``[1 - colour, 1 + colour]``        0.08
contrast        factor in ``[1 - contrast, 1 + contrast]`` about the        0.25
                patch's mean
brightness      offset in ``[-brightness, brightness]`` grey levels         20
gamma           ``255 (x / 255) ** g``, ``log g`` in                        0.25
                ``[-log(1 + gamma), log(1 + gamma)]``
noise           Gaussian, standard deviation in ``[0, noise]`` grey        4
                levels, one draw per pixel, the same on the three
                channels (luminance noise: a third of the draws)
head pose       per sample: Gaussian noise of standard deviation            0 (off)
                ``head_pose_deg`` degrees on each angle of the head-pose
                input (not on the label): test-time head poses come from
                PnP, off by a few degrees; drawn after the patches'
                augmentation
mirror          with probability ``mirror`` per sample, both patches        0 (off)
                mirrored left-right and swapped (the mirrored left eye
                is a right eye), the yaw of the gaze and of the head
                pose negated (:func:`facemesh.conventions.mirror_pitchyaw`);
                drawn and applied first, by :func:`mirror_samples`
==============  =========================================================  ==============

applied in this order (the mirror before the others, then the zoom), the values clipped
to [0, 255] after the brightness and after the noise. The left and the right eye of a sample get **independent
draws** (the model sees each eye through the shared backbone; a sample's eyes
need not look alike). Nothing is drawn when :attr:`TrainAugment.enabled` is
False: ``TrainAugment(enabled=False)`` (``gazeaug train --no-augment``) trains
on the patches as they are.

**No JPEG compression**: it cannot run on the device (there is no JPEG encoder
among PyTorch's tensor operations), and encoding on the CPU would make the CPU
the bottleneck of GPU training. ``gazeaug simulate`` draws a JPEG quality per
image (:class:`gazeaug.simulate.SimSettings`) instead.

Randomness: one ``torch.Generator`` on the patches' device per epoch, seeded
from the training seed and the epoch (:func:`augment_generator`), so a run is
reproducible and a resumed run augments as the uninterrupted one did. The
draws differ between devices (the CPU's and CUDA's generators differ).

The augmentation works on the raw patches; the model's input normalization
(:func:`gazeaug.models.preprocess.scale_eyes`, e.g. grey + histogram
equalization, which undoes much of the brightness, contrast and gamma
changes) comes after it, as at inference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from .errors import GazeAugError
from .models import import_torch
from .models.preprocess import eyes_to_float

__all__ = [
    "STRENGTHS",
    "TrainAugment",
    "augment_eyes",
    "augment_eyes_and_points",
    "augment_generator",
    "jitter_head_pose",
    "mirror_samples",
    "translate_blur",
    "zoom_patches",
]


def _number(v: Any) -> bool:
    return (
        isinstance(v, (int, float, np.integer, np.floating))
        and not isinstance(v, (bool, np.bool_))
        and math.isfinite(v)
    )


@dataclass(frozen=True)
class TrainAugment:
    """Strengths of the training-time augmentation (see the module docstring); 0 turns one off.

    Attributes:
        enabled: augment at all (default True); False trains on the patches as they are.
        shift_px: largest translation, pixels per axis, an integer in [0, 16] (default 10: the framing
            of test-time normalization, from detected landmarks, moves an eye's contour centre by
            1.1 px median and 3.9 px at the 95th percentile, and each person's eyes by up to 5 px
            more; docs/model.md).
        blur_sigma: largest Gaussian blur sigma, pixels, in [0, 3] (default 1.2).
        colour: per-channel gain spread, in [0, 1) (default 0.08: gains 0.92 to 1.08).
        contrast: contrast factor spread about the patch mean, in [0, 1) (default 0.25).
        brightness: largest offset, grey levels, in [0, 128] (default 20).
        gamma: gamma spread, in [0, 4]: exponents from 1 / (1 + gamma) to 1 + gamma (default 0.25).
        noise: largest standard deviation of the pixel noise, grey levels, in [0, 64] (default 4).
        mirror: probability that a sample is mirrored left-right (eyes swapped, yaws negated), in
            [0, 1] (default 0: off; on 1800 simulated images 0.5 read new people at 8.43 deg against
            8.60 without, one seed; on issue 13's reference recipe 7.56 against 7.68 over three
            draws, 2026-12-01: within noise; docs/model.md).
        scale: largest relative zoom of a patch, in [0, 0.5]: factors drawn uniformly in
            [1 - scale, 1 + scale] (default 0: off). A zoom about the principal point is the
            normalized camera with another focal length, so the labels are kept; it varies the eye's
            size in the patch, which the normalization leaves to each person's eyes and to how far
            their face differs from the generic face the head pose is fitted to (docs/model.md).
        head_pose_deg: standard deviation of the Gaussian noise added to each angle (pitch, yaw) of
            the head-pose input, degrees, in [0, 20] (default 0: off). The gaze label is left as it
            is: the noise stands for the error of the head pose a test image gets from PnP against a
            generic face (2-4 deg on issue 13's simulated people, docs/model.md), which a model
            trained on exact poses takes at face value.

    Raises:
        GazeAugError: a value of the wrong type or outside its range.
    """

    enabled: bool = True
    shift_px: int = 10
    blur_sigma: float = 1.2
    colour: float = 0.08
    contrast: float = 0.25
    brightness: float = 20.0
    gamma: float = 0.25
    noise: float = 4.0
    mirror: float = 0.0
    head_pose_deg: float = 0.0
    scale: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, (bool, np.bool_)):
            raise GazeAugError(f"enabled: expected True or False, got {self.enabled!r}")
        if not (isinstance(self.shift_px, (int, np.integer)) and not isinstance(self.shift_px, (bool, np.bool_))):
            raise GazeAugError(f"shift_px: expected an integer in [0, 16] pixels, got {self.shift_px!r}")
        if not 0 <= self.shift_px <= 16:
            raise GazeAugError(f"shift_px: expected an integer in [0, 16] pixels, got {self.shift_px!r}")
        bounds = {  # name: (low, high, high included, unit)
            "blur_sigma": (0.0, 3.0, True, " pixels"),
            "colour": (0.0, 1.0, False, ""),
            "contrast": (0.0, 1.0, False, ""),
            "brightness": (0.0, 128.0, True, " grey levels"),
            "gamma": (0.0, 4.0, True, ""),
            "noise": (0.0, 64.0, True, " grey levels"),
            "mirror": (0.0, 1.0, True, ""),
            "head_pose_deg": (0.0, 20.0, True, " degrees"),
            "scale": (0.0, 0.5, True, ""),
        }
        for name, (lo, hi, closed, unit) in bounds.items():
            v = getattr(self, name)
            if not (_number(v) and lo <= v and (v <= hi if closed else v < hi)):
                interval = f"[{lo:g}, {hi:g}{']' if closed else ')'}"
                raise GazeAugError(f"{name}: expected a number in {interval}{unit}, got {v!r}")
            object.__setattr__(self, name, float(v))  # plain numbers: model files record them
        object.__setattr__(self, "shift_px", int(self.shift_px))
        object.__setattr__(self, "enabled", bool(self.enabled))


#: The names of :class:`TrainAugment`'s strengths, in its order (every field but ``enabled``):
#: what ``gazeaug train --augment NAME=VALUE`` sets.
STRENGTHS: tuple[str, ...] = tuple(f.name for f in fields(TrainAugment) if f.name != "enabled")


def augment_generator(seed: int, epoch: int, device: Any = "cpu") -> Any:
    """The ``torch.Generator`` on ``device`` that augments epoch ``epoch`` (0-based) of a run seeded ``seed``."""
    torch = import_torch()
    state = np.random.SeedSequence([int(seed), int(epoch), 0x61756720]).generate_state(2, np.uint32)
    g = torch.Generator(device=device)
    g.manual_seed(int(state[0]) << 31 ^ int(state[1]))
    return g


def _reflect(idx: Any, size: int) -> Any:
    """Indices reflected into [0, size) about the border pixels (numpy's and PyTorch's 'reflect', repeated)."""
    if size == 1:
        return idx * 0
    period = 2 * (size - 1)
    i = idx.remainder(period)
    return i.where(i < size, period - i)


#: Largest patch side blurred by matrix products (faster on the CPU than a depthwise convolution);
#: larger patches use the convolution (the matrices grow as the side squared).
_MATMUL_MAX_SIDE = 128


def _kernels(sigma: Any, shift: Any, radius: int, reach: int) -> tuple[Any, Any]:
    """Tap offsets (T,) int64 and weights (N, T) float32 of the shifted Gaussian: out[i] = sum w[t] in[i + off[t]].

    ``reach``: the largest offset, ``radius`` + the largest shift.
    """
    torch = import_torch()
    off = torch.arange(-reach, reach + 1, device=sigma.device)
    s = sigma.float().clamp(min=1e-3).unsqueeze(1)  # below: a delta (exp underflows to 0 off the centre)
    d = (off.unsqueeze(0) + shift.unsqueeze(1)).float()  # distance of each tap from the source centre i - shift
    w = torch.exp(-0.5 * (d / s) ** 2) * (d.abs() <= radius)
    return off, w / w.sum(1, keepdim=True)


def _matrices(sigma: Any, shift: Any, radius: int, reach: int, size: int) -> Any:
    """(N, size, size) float32: row i holds the weights of the source pixels of output pixel i."""
    torch = import_torch()
    off, w = _kernels(sigma, shift, radius, reach)
    n = w.shape[0]
    src = _reflect(torch.arange(size, device=w.device).view(1, size, 1) + off.view(1, 1, -1), size)
    m = torch.zeros((n, size, size), device=w.device, dtype=torch.float32)
    return m.scatter_add_(2, src.expand(n, -1, -1), w.unsqueeze(1).expand(-1, size, -1))


def translate_blur(
    eyes: Any, shift_yx: Any, sigma: Any, radius: int, *, max_shift: int | None = None, method: str = "auto"
) -> Any:
    """Translate every patch by whole pixels and blur it with a Gaussian, each with its own parameters.

    ``out[y, x] = sum G(j) G(k) eyes[y - dy + j, x - dx + k]`` over ``|j|, |k| <= radius``, ``G`` the
    normalized Gaussian of the patch's sigma, indices reflected at the borders (numpy's 'reflect':
    a pad-reflect and a crop); sigma 0 is a pure translation (exact), shift 0 a pure blur.

    Args:
        eyes: float32 torch tensor (N, C, H, W), any device.
        shift_yx: int64 (N, 2), the same device: (down, right) pixels; a positive shift moves the
            content down and to the right.
        sigma: float32 (N,), pixels, the same device.
        radius: kernel half-width, pixels (``ceil(3 * largest sigma)``).
        max_shift: a bound of ``|shift_yx|`` (default: read from the tensor, which waits for a GPU).
        method: ``matmul`` (two matrix products per patch: the separable kernels as banded matrices),
            ``conv`` (a depthwise convolution, per-patch kernels; ``matmul`` where the kernel reaches
            beyond the side) or ``auto`` (``matmul`` for sides up to 128 pixels). The same result up
            to rounding.

    Returns:
        float32 (N, C, H, W) in channels-last memory order (as the uint8 (N, H, W, C) patches: the
        model trains fastest on it), the same device.
    """
    torch = import_torch()
    n, c, h, w = eyes.shape
    if n == 0:
        return eyes
    reach = radius + (int(shift_yx.abs().max()) if max_shift is None else int(max_shift))
    if method == "auto":
        method = "matmul" if max(h, w) <= _MATMUL_MAX_SIDE else "conv"
    if method == "matmul" or reach >= min(h, w):  # a reflect pad must be shorter than the side
        mv = _matrices(sigma, shift_yx[:, 0], radius, reach, h)  # (N, H, H)
        mh = _matrices(sigma, shift_yx[:, 1], radius, reach, w)  # (N, W, W)
        y = torch.bmm(mv, eyes.transpose(1, 2).reshape(n, h, c * w))  # rows: (N, H, C*W)
        y = torch.bmm(y.view(n, h * c, w), mh.transpose(1, 2))  # columns: (N, H*C, W)
        return y.view(n, h, c, w).transpose(1, 2).contiguous(memory_format=torch.channels_last)
    fn = torch.nn.functional
    _, wv = _kernels(sigma, shift_yx[:, 0], radius, reach)
    _, wh = _kernels(sigma, shift_yx[:, 1], radius, reach)
    x = fn.pad(eyes.reshape(1, n * c, h, w), (reach, reach, reach, reach), mode="reflect")
    x = fn.conv2d(x, wh.repeat_interleave(c, 0).view(n * c, 1, 1, -1), groups=n * c)
    x = fn.conv2d(x, wv.repeat_interleave(c, 0).view(n * c, 1, -1, 1), groups=n * c)
    return x.view(n, c, h, w).contiguous(memory_format=torch.channels_last)


def zoom_patches(eyes: Any, factors: Any) -> Any:
    """Zoom every patch about the normalized camera's principal point by its own factor.

    ``out(q) = eyes(c + (q - c) / f)``, ``c`` the principal point ``(w / 2, h / 2)`` (pixel centres
    at whole numbers; :func:`facemesh.conventions.principal_point_grid_coordinates`), sampled
    bilinearly, positions beyond the border reflected about the patch's edges (``grid_sample``'s
    ``reflection``). A factor above 1 enlarges the content: the same normalized camera with ``f``
    times its focal length, so the gaze and head-pose labels hold as they are.

    Args:
        eyes: float32 torch tensor (N, C, H, W), any device.
        factors: float32 (N,), the same device: the zoom factors (> 0).

    Returns:
        float32 (N, C, H, W) in channels-last memory order, the same device.
    """
    torch = import_torch()
    from facemesh.conventions import principal_point_grid_coordinates

    n, c, h, w = eyes.shape
    if n == 0:
        return eyes
    cx, cy = principal_point_grid_coordinates(w, h)
    inv = factors.float().reciprocal()
    theta = torch.zeros((n, 2, 3), dtype=torch.float32, device=eyes.device)
    theta[:, 0, 0], theta[:, 1, 1] = inv, inv
    theta[:, 0, 2], theta[:, 1, 2] = (1 - inv) * cx, (1 - inv) * cy
    fn = torch.nn.functional
    grid = fn.affine_grid(theta, [n, c, h, w], align_corners=False)
    out = fn.grid_sample(eyes.contiguous(), grid, mode="bilinear", padding_mode="reflection", align_corners=False)
    return out.contiguous(memory_format=torch.channels_last)


def jitter_head_pose(head: Any, augment: TrainAugment, generator: Any) -> Any:
    """The head-pose input with Gaussian noise of ``augment.head_pose_deg`` degrees on each angle.

    Args:
        head: float32 torch tensor (N, 2), radians (pitch, yaw), normalized face frame, on the
            device that trains.
        augment: the strengths.
        generator: a ``torch.Generator`` on the same device (:func:`augment_generator`).

    Returns:
        A new float32 (N, 2) tensor, radians; ``head`` itself when the augmentation is off or the
        strength is 0: then nothing is drawn, so runs that do not ask for it draw every other
        augmentation exactly as before the option existed (one of the two exceptions, with the
        zoom, to "a strength set to 0 changes no other draw").
    """
    torch = import_torch()
    if not augment.enabled or augment.head_pose_deg == 0 or head.shape[0] == 0:
        return head
    noise = torch.randn(tuple(head.shape), generator=generator, device=head.device, dtype=torch.float32)
    return head + noise.mul_(math.radians(augment.head_pose_deg)).to(head.dtype)


def mirror_samples(
    eyes: Any,
    head_pose: Any,
    gaze: Any,
    augment: TrainAugment,
    generator: Any,
    face: Any = None,
    keypoints: Any = None,
) -> tuple[Any, Any, Any, Any, Any]:
    """Mirror a random share (``augment.mirror``) of a batch's samples left-right.

    A mirrored sample's left patch is its right patch mirrored about the normalized camera's
    principal point (column ``x`` from column ``w - x``,
    :func:`facemesh.conventions.mirrored_columns`) and its right patch the left one
    mirrored; its gaze and head pose have their yaw negated
    (:data:`facemesh.conventions.MIRROR_PITCHYAW`). One draw per sample is always made
    (also with ``mirror`` 0), so the strength changes no other draw; nothing is drawn
    when ``augment.enabled`` is False.

    Args:
        eyes: uint8 torch tensor (2B, H, W, 3) RGB: the B left patches, then the B right ones.
        head_pose: float32 torch tensor (B, 2), radians, (pitch, yaw), the face's normalized frame.
        gaze: float32 torch tensor (B, 2), radians, (pitch, yaw), the face's normalized frame.
        augment: the strengths.
        generator: a ``torch.Generator`` on the tensors' device.
        face: uint8 torch tensor (B, Hf, Wf, 3) RGB, the face patches, or None; a mirrored
            sample's face is mirrored about its own principal point.
        keypoints: float32 torch tensor (B, 2, K, 2), px: each sample's eyes (left, right), K
            points, (u, v) in the eye's patch (:data:`gazeaug.normalize.EYE_KEYPOINTS`), or None; a
            mirrored sample's left eye takes the right eye's points at ``u -> w - u`` and the
            other way round.

    Returns:
        (eyes, head_pose, gaze, face, keypoints) of the same shapes, dtypes and device (face and
        keypoints None when not given).
    """
    torch = import_torch()
    b = gaze.shape[0]
    if not augment.enabled or b == 0:
        return eyes, head_pose, gaze, face, keypoints
    from facemesh.conventions import MIRROR_PITCHYAW, mirrored_columns

    flip = torch.rand(b, generator=generator, device=eyes.device) < augment.mirror
    if augment.mirror == 0:  # decided on the host: no wait for the device
        return eyes, head_pose, gaze, face, keypoints
    left, right = eyes[:b], eyes[b:]
    cols = torch.as_tensor(mirrored_columns(eyes.shape[2]), device=eyes.device)
    f4 = flip[:, None, None, None]
    eyes = torch.cat([torch.where(f4, right[:, :, cols], left), torch.where(f4, left[:, :, cols], right)])
    if face is not None:
        face_cols = torch.as_tensor(mirrored_columns(face.shape[2]), device=face.device)
        face = torch.where(f4, face[:, :, face_cols], face)
    sign = torch.as_tensor(MIRROR_PITCHYAW, dtype=gaze.dtype, device=gaze.device)
    factor = torch.where(flip[:, None], sign, torch.ones_like(sign))
    if keypoints is not None:  # u -> w - u (the columns' mirror), the eyes swapped
        swapped = keypoints.flip(1).clone()
        swapped[..., 0] = eyes.shape[2] - swapped[..., 0]
        keypoints = torch.where(flip[:, None, None, None], swapped, keypoints)
    return eyes, head_pose * factor, gaze * factor, face, keypoints


def augment_eyes(eyes: Any, augment: TrainAugment, generator: Any) -> Any:
    """:func:`augment_eyes_and_points` without points: the augmented patches alone."""
    return augment_eyes_and_points(eyes, None, augment, generator)[0]


def augment_eyes_and_points(eyes: Any, points: Any, augment: TrainAugment, generator: Any) -> tuple[Any, Any]:
    """Augment a batch of eye patches on their device (see the module docstring).

    The points of each patch, when given, move with its content: the zoom takes ``p`` to
    ``c + f (p - c)`` (``c`` the principal point (w / 2, h / 2)), the translation adds
    ``(right, down)``; the other operations leave them. The same draws either way.

    Args:
        eyes: uint8 torch tensor (N, H, W, 3) RGB, on the device that trains (the left and the right
            eyes of a batch stacked: every patch gets its own draws).
        points: float32 torch tensor (N, K, 2), px, (u, v) in each patch (pixel centres at whole
            numbers), the same device, or None (NaN stays NaN).
        augment: the strengths.
        generator: a ``torch.Generator`` on the same device (:func:`augment_generator`).

    Returns:
        (patches, points): float32 (N, 3, H, W), RGB, in [0, 255] grey levels (not rounded), in
        channels-last memory order (the model trains fastest on it, about 1.5 x on the CPU), the
        same device: ready for :func:`gazeaug.models.preprocess.scale_eyes`; the points moved (None
        when not given). With ``augment.enabled`` False, the patches and points as they are
        (nothing drawn).
    """
    torch = import_torch()
    if not augment.enabled or eyes.shape[0] == 0:
        return eyes_to_float(eyes), points
    n, dev, g = eyes.shape[0], eyes.device, generator

    def uniform(lo: float, hi: float, *shape: int) -> Any:
        return torch.rand((n, *shape), generator=g, device=dev).mul_(hi - lo).add_(lo)

    # every draw always made, in a fixed order: a strength set to 0 changes no other draw (the zoom
    # excepted, below)
    shift = torch.randint(-augment.shift_px, augment.shift_px + 1, (n, 2), generator=g, device=dev)
    sigma = uniform(0.0, augment.blur_sigma)
    gain = uniform(1 - augment.colour, 1 + augment.colour, 3)
    contrast = uniform(1 - augment.contrast, 1 + augment.contrast)
    offset = uniform(-augment.brightness, augment.brightness)
    log_gamma = math.log1p(augment.gamma)
    gamma = uniform(-log_gamma, log_gamma).exp_()
    noise_std = uniform(0.0, augment.noise)
    # drawn only when asked for (after every draw but the pixel noise's, which it then moves): a run
    # without it draws as before it existed
    zoom = uniform(1 - augment.scale, 1 + augment.scale) if augment.scale > 0 else None
    x = eyes_to_float(eyes)
    if points is not None:
        h, w = eyes.shape[1:3]
        centre = torch.tensor([w / 2.0, h / 2.0], dtype=points.dtype, device=dev)
        if zoom is not None:
            points = centre + (points - centre) * zoom.view(n, 1, 1).to(points.dtype)
        if augment.shift_px:
            points = points + shift.flip(1).view(n, 1, 2).to(points.dtype)  # (down, right) -> (u, v)
    if zoom is not None:
        x = zoom_patches(x, zoom)
    if augment.shift_px or augment.blur_sigma > 0:
        x = translate_blur(x, shift, sigma, math.ceil(3 * augment.blur_sigma), max_shift=augment.shift_px)
    x = x * gain.view(n, 3, 1, 1)
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    x = x.sub_(mean).mul_(contrast.view(n, 1, 1, 1)).add_(mean + offset.view(n, 1, 1, 1)).clamp_(0, 255)
    if augment.gamma > 0:
        x = x.div_(255.0).pow_(gamma.view(n, 1, 1, 1)).mul_(255.0)
    if augment.noise > 0:  # one draw per pixel, the same on the three channels (luminance noise)
        noise = torch.randn((n, 1, *x.shape[2:]), generator=g, device=dev)
        x = x.add_(noise.mul_(noise_std.view(n, 1, 1, 1)))
    return x.clamp_(0, 255), points
