"""Head poses for the target application: a bivariate normal over (yaw, pitch), or one derived from a camera rig.

A drawn ``(yaw, pitch)`` parametrises the paper's rotation
``R(y, p) = R_pitch(p) R_yaw(y)`` (:func:`facemesh.conventions.rotation_from_yaw_pitch`)
that takes the frontal head (looking into the camera) to the augmented pose:
positive pitch turns the face up, i.e. the camera sees it from below (the
paper's wheelchair camera, 30 deg below the line of sight, gives pitch +30).

The paper's equation gives the covariance as ``[[10, 0], [0, 10]]`` deg^2 (a
standard deviation of 3.16 deg); its text says "a variance of 10 degrees",
which many read as a standard deviation of 10 deg. :class:`HeadPoseDistribution`
takes a covariance (the default is the equation's); ``from_std`` builds the
other reading. Both are offered on the command line (``--yaw-var`` /
``--yaw-std``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from facemesh.conventions import look_at_rotation, rotation_from_yaw_pitch, yaw_pitch_from_rotation
from facemesh.types import CameraIntrinsics

from .errors import GazeAugError
from .scene import Plane, Scene, Target, plane_from_dict, target_from_dict

__all__ = ["HeadPoseDistribution", "Rig", "load_rig", "rig_from_dict", "BUILTIN_RIGS"]


@dataclass(frozen=True)
class HeadPoseDistribution:
    """Bivariate normal over the head's (yaw, pitch), degrees.

    Attributes:
        mean_deg: (yaw, pitch) mean, degrees (default (0, 30): the paper's wheelchair camera).
        cov_deg2: 2 x 2 covariance of (yaw, pitch), deg^2 (default ``[[10, 0], [0, 10]]``, the paper's equation).
    """

    mean_deg: tuple[float, float] = (0.0, 30.0)
    cov_deg2: tuple[tuple[float, float], tuple[float, float]] = ((10.0, 0.0), (0.0, 10.0))

    def __post_init__(self) -> None:
        m = np.asarray(self.mean_deg, dtype=np.float64)
        c = np.asarray(self.cov_deg2, dtype=np.float64)
        if m.shape != (2,) or not np.all(np.isfinite(m)):
            raise GazeAugError(f"head-pose mean: expected finite (yaw, pitch) degrees, got {self.mean_deg}")
        if c.shape != (2, 2) or not np.all(np.isfinite(c)):
            raise GazeAugError(f"head-pose covariance: expected a finite 2 x 2 matrix (deg^2), got {self.cov_deg2}")
        if not np.allclose(c, c.T):
            raise GazeAugError(f"head-pose covariance: expected a symmetric matrix, got {c.tolist()}")
        if c[0, 0] < 0 or c[1, 1] < 0:
            raise GazeAugError(f"head-pose variances must be >= 0, got yaw {c[0, 0]} and pitch {c[1, 1]} deg^2")
        if np.linalg.eigvalsh(c).min() < -1e-9 * max(1.0, abs(c).max()):
            raise GazeAugError(f"head-pose covariance: expected positive semi-definite, got {c.tolist()}")
        if abs(m[1]) >= 90:
            raise GazeAugError(f"head-pose pitch mean must lie in (-90, 90) degrees, got {m[1]}")
        object.__setattr__(self, "mean_deg", (float(m[0]), float(m[1])))
        object.__setattr__(self, "cov_deg2", ((float(c[0, 0]), float(c[0, 1])), (float(c[1, 0]), float(c[1, 1]))))

    @classmethod
    def from_variance(
        cls, yaw_mean: float = 0.0, pitch_mean: float = 30.0, yaw_var: float = 10.0, pitch_var: float = 10.0
    ) -> HeadPoseDistribution:
        """Independent yaw and pitch with the given means (deg) and variances (deg^2)."""
        return cls((yaw_mean, pitch_mean), ((yaw_var, 0.0), (0.0, pitch_var)))

    @classmethod
    def from_std(
        cls, yaw_mean: float = 0.0, pitch_mean: float = 30.0, yaw_std: float = 10.0, pitch_std: float = 10.0
    ) -> HeadPoseDistribution:
        """Independent yaw and pitch with the given means and standard deviations (deg)."""
        for name, v in (("yaw", yaw_std), ("pitch", pitch_std)):
            if not (math.isfinite(v) and v >= 0):
                raise GazeAugError(f"{name} standard deviation must be finite and >= 0, got {v}")
        return cls.from_variance(yaw_mean, pitch_mean, yaw_std**2, pitch_std**2)

    def sample(self, n: int, rng: np.random.Generator | int | None = None) -> NDArray[np.float64]:
        """Draw n poses.

        Args:
            n: number of poses.
            rng: a numpy Generator or a seed (same seed, same poses).

        Returns:
            (n, 2) float64 radians, (yaw, pitch) columns.
        """
        g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        draws = g.multivariate_normal(np.asarray(self.mean_deg), np.asarray(self.cov_deg2), size=int(n), method="eigh")
        return np.radians(draws)

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable form."""
        return {"mean_deg": list(self.mean_deg), "cov_deg2": [list(r) for r in self.cov_deg2]}


def _is_real(v: Any) -> bool:
    """A real number (int, float or numpy scalar), not a bool."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _is_int(v: Any) -> bool:
    """An integer (int or numpy integer), not a bool."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


@dataclass(frozen=True)
class Rig:
    """Where the application's camera sits relative to the user's head, and how the head moves.

    The *rig frame* is the head frame of the user sitting still and looking
    straight ahead: origin between the eyes, x toward the user's left, y down,
    z from the face back into the head (so the space in front of the face has
    negative z).

    Attributes:
        name: label recorded in outputs.
        camera_position_mm: (3,) the camera centre in the rig frame. The wheelchair
            example: 400 mm in front and 230 mm below the eyes, ``(0, 230, -400)``.
        head_yaw_std_deg, head_pitch_std_deg: spread of the head's own turning (deg, standard deviations).
        head_yaw_mean_deg, head_pitch_mean_deg: the head's mean turn away from straight ahead (deg,
            same convention: positive pitch = looking up, positive yaw = toward the user's right).
        image_size_wh: the camera's image size (for the simulator): integers, 32 to 8192 px per side.
        focal_px: the camera's focal length in pixels (principal point at the image centre), finite,
            > 0 and < 1e6.
        target_box_mm: ((x0, y0, z0), (x1, y1, z1)) corners of the box, rig frame, where the
            targets the user looks at lie (drawn uniformly).
        head_position_std_mm: spread of the head's position around the rig frame's origin.
        targets: what the user selects by looking at it (:mod:`gazeaug.scene`: spheres and boxes,
            rig frame, mm); optional in a rig file (default none).
        planes: surfaces that give a point of gaze (a table, a screen; :class:`gazeaug.scene.Plane`);
            optional in a rig file (default none).

    A rig file (:func:`load_rig`) gives every field but ``name``, ``targets`` and ``planes``; the
    defaults here serve code only.
    """

    name: str = "custom"
    camera_position_mm: tuple[float, float, float] = (0.0, 230.0, -400.0)
    head_yaw_std_deg: float = 5.0
    head_pitch_std_deg: float = 5.0
    head_yaw_mean_deg: float = 0.0
    head_pitch_mean_deg: float = 0.0
    image_size_wh: tuple[int, int] = (640, 480)
    focal_px: float = 600.0
    target_box_mm: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (-250.0, 0.0, -600.0),
        (250.0, 300.0, -600.0),
    )
    head_position_std_mm: float = 15.0
    targets: tuple[Target, ...] = ()
    planes: tuple[Plane, ...] = ()

    #: Allowed image width and height, pixels (a simulated image is held whole in memory, with its depth
    #: and several layers: 8192 x 8192 is already a few GB).
    IMAGE_SIDE_RANGE: ClassVar[tuple[int, int]] = (32, 8192)
    #: The focal length must stay below this, pixels (a field of view of 0.05 deg over 8192 px).
    MAX_FOCAL_PX: ClassVar[float] = 1e6

    def __post_init__(self) -> None:
        c = np.asarray(self.camera_position_mm, dtype=np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise GazeAugError(f"rig {self.name!r}: camera_position_mm: expected finite (x, y, z) mm, got {c}")
        if c[2] >= 0:
            raise GazeAugError(f"rig {self.name!r}: the camera must be in front of the face (z < 0), got z = {c[2]}")
        for f in ("head_yaw_std_deg", "head_pitch_std_deg", "head_yaw_mean_deg", "head_pitch_mean_deg"):
            v = getattr(self, f)
            if not (_is_real(v) and math.isfinite(v)) or (f.endswith("std_deg") and v < 0):
                raise GazeAugError(
                    f"rig {self.name!r}: {f} must be a finite number{' >= 0' if 'std' in f else ''}, got {v!r}"
                )
            object.__setattr__(self, f, float(v))
        object.__setattr__(self, "camera_position_mm", tuple(float(x) for x in c))
        lo, hi = self.IMAGE_SIDE_RANGE
        size = self.image_size_wh
        if not (isinstance(size, (tuple, list)) and len(size) == 2 and all(_is_int(v) and lo <= v <= hi for v in size)):
            raise GazeAugError(
                f"rig {self.name!r}: image_size_wh: expected two integers (width, height), "
                f"each from {lo} to {hi} px, got {size!r}"
            )
        object.__setattr__(self, "image_size_wh", (int(size[0]), int(size[1])))
        focal = self.focal_px
        if not (_is_real(focal) and math.isfinite(focal) and 0 < focal < self.MAX_FOCAL_PX):
            raise GazeAugError(
                f"rig {self.name!r}: focal_px: expected a number > 0 and < {self.MAX_FOCAL_PX:g} px, got {focal!r}"
            )
        object.__setattr__(self, "focal_px", float(focal))
        p = self.head_position_std_mm
        if not (_is_real(p) and math.isfinite(p) and p >= 0):
            raise GazeAugError(f"rig {self.name!r}: head_position_std_mm: expected a finite number >= 0, got {p!r}")
        object.__setattr__(self, "head_position_std_mm", float(p))
        box = np.asarray(self.target_box_mm, dtype=np.float64)
        if box.shape != (2, 3) or not np.isfinite(box).all() or (box[0] > box[1]).any():
            raise GazeAugError(f"rig {self.name!r}: target_box_mm: expected [[x0, y0, z0], [x1, y1, z1]], min <= max")
        if box[1, 2] >= 0:
            raise GazeAugError(f"rig {self.name!r}: targets must lie in front of the face (z < 0)")
        object.__setattr__(self, "target_box_mm", (tuple(float(v) for v in box[0]), tuple(float(v) for v in box[1])))
        object.__setattr__(self, "targets", tuple(self.targets))
        object.__setattr__(self, "planes", tuple(self.planes))
        try:
            Scene(self.targets, self.planes)  # checks the types' invariants: unique names
        except GazeAugError as exc:
            raise GazeAugError(f"rig {self.name!r}: {exc}") from exc

    def camera(self) -> CameraIntrinsics:
        """The rig camera's intrinsics.

        ``focal_px``, the principal point at the centre of an ``image_size_wh`` image
        (``((w - 1) / 2, (h - 1) / 2)``, pixel centres at integers), no distortion.
        """
        w, h = self.image_size_wh
        f = self.focal_px
        k = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
        return CameraIntrinsics(matrix=k, distortion=np.zeros(5), image_size=(w, h), source=f"rig:{self.name}")

    @property
    def scene(self) -> Scene:
        """The rig's targets and planes (rig frame, mm)."""
        return Scene(self.targets, self.planes)

    def head_poses(self, n: int, rng: np.random.Generator | int | None = None) -> NDArray[np.float64]:
        """Head poses as this camera sees them: (n, 2) float64 radians, the (yaw, pitch) of ``R(y, p)``.

        Each draw turns the head by ``R(yaw, pitch)`` in the rig frame, then
        expresses it in the frame of a camera at ``camera_position_mm`` looking
        at the head (its forward axis along the line of sight to the eyes, its
        x axis level with the rig's x), which is how normalization sees it.
        """
        g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        yaw = np.radians(self.head_yaw_mean_deg + self.head_yaw_std_deg * g.standard_normal(int(n)))
        pitch = np.radians(self.head_pitch_mean_deg + self.head_pitch_std_deg * g.standard_normal(int(n)))
        r_cam = self.camera_rotation()
        out = np.empty((int(n), 2))
        for i in range(int(n)):
            # head frame -> rig frame is R(y, p) (rig frame = frontal head frame); rig -> camera is r_cam
            out[i] = yaw_pitch_from_rotation(r_cam @ rotation_from_yaw_pitch(yaw[i], pitch[i]))
        return out

    def camera_rotation(self) -> NDArray[np.float64]:
        """(3, 3) rig frame -> camera frame: forward toward the eyes, x level with the rig's x axis."""
        try:
            return look_at_rotation(-np.asarray(self.camera_position_mm), right=[1.0, 0.0, 0.0])
        except ValueError as exc:
            raise GazeAugError(f"rig {self.name!r}: the camera lies on the line through both eyes") from exc

    def distribution(self, n: int = 20000, seed: int = 0) -> HeadPoseDistribution:
        """The bivariate normal that fits this rig's head poses (mean and covariance of many draws)."""
        d = np.degrees(self.head_poses(n, seed))
        cov = np.cov(d.T)
        cov = (cov + cov.T) / 2
        return HeadPoseDistribution((float(d[:, 0].mean()), float(d[:, 1].mean())), (tuple(cov[0]), tuple(cov[1])))

    def as_dict(self) -> dict[str, Any]:
        """JSON/YAML-serialisable form (the RIG.yaml fields)."""
        return {
            "name": self.name,
            "camera_position_mm": list(self.camera_position_mm),
            "head_yaw_std_deg": self.head_yaw_std_deg,
            "head_pitch_std_deg": self.head_pitch_std_deg,
            "head_yaw_mean_deg": self.head_yaw_mean_deg,
            "head_pitch_mean_deg": self.head_pitch_mean_deg,
            "image_size_wh": list(self.image_size_wh),
            "focal_px": self.focal_px,
            "target_box_mm": [list(c) for c in self.target_box_mm],
            "head_position_std_mm": self.head_position_std_mm,
            **({"targets": [t.as_dict() for t in self.targets]} if self.targets else {}),
            **({"planes": [p.as_dict() for p in self.planes]} if self.planes else {}),
        }


#: Built-in rigs.
#:
#: ``wheelchair``: the paper's application. The camera is 460 mm from the eyes,
#: 30 deg below their horizontal line of sight, pointing at them; the head is
#: level on average (so the camera sees it pitched +30 deg, the paper's
#: assumption); the user looks at objects within a robot arm's reach, in
#: front and below.
#:
#: ``screen``: a dataset-like setup (MPIIFaceGaze's laptops): a webcam at the top
#: of a screen about at eye level, 550 mm away; the targets lie on the screen,
#: below the camera; the head turns and tilts naturally.
BUILTIN_RIGS = {
    "wheelchair": Rig(
        name="wheelchair",
        camera_position_mm=(0.0, 460.0 * math.sin(math.radians(30)), -460.0 * math.cos(math.radians(30))),
        head_yaw_std_deg=10.0,
        head_pitch_std_deg=5.0,
        target_box_mm=((-300.0, 50.0, -650.0), (300.0, 300.0, -350.0)),
    ),
    "screen": Rig(
        name="screen",
        camera_position_mm=(0.0, -20.0, -550.0),
        head_yaw_std_deg=10.0,
        head_pitch_std_deg=6.0,
        head_pitch_mean_deg=-8.0,
        target_box_mm=((-200.0, 0.0, -550.0), (200.0, 250.0, -550.0)),
    ),
}


def load_rig(spec: str | Path) -> Rig:
    """A built-in rig by name (``wheelchair``, ``screen``) or a YAML/JSON file with :class:`Rig`'s fields.

    A file gives every field of :class:`Rig` but ``name`` (the file's stem when absent): a field left
    out is an error, never a default, so a truncated file cannot pass for a rig it is not.

    Raises:
        GazeAugError: unknown name, unreadable file, missing, unknown or bad fields.
    """
    if str(spec) in BUILTIN_RIGS:
        return BUILTIN_RIGS[str(spec)]
    p = Path(spec)
    try:
        if not p.is_file():
            raise GazeAugError(f"rig {spec!r}: not a built-in rig ({', '.join(BUILTIN_RIGS)}) and no such file")
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise GazeAugError(f"{p}: cannot read the rig file ({exc.strerror or exc.__class__.__name__})") from exc
    try:
        if p.suffix.lower() == ".json":
            import json

            data = json.loads(text)
        else:
            import yaml

            data = yaml.safe_load(text)
    except Exception as exc:  # noqa: BLE001 - any parse error becomes a clear message
        raise GazeAugError(f"{p}: not valid {p.suffix.lstrip('.').upper() or 'YAML'} ({exc})") from exc
    if not isinstance(data, dict):
        raise GazeAugError(f"{p}: expected a mapping of rig fields, got {type(data).__name__}")
    try:
        lines = _yaml_lines(text) if p.suffix.lower() != ".json" else {}
    except GazeAugError as exc:
        raise GazeAugError(f"{p}, {exc}") from exc

    def at(key: Any) -> str:
        return f"{p}, line {lines[key]}" if key in lines else str(p)

    fields = [f.name for f in dataclasses.fields(Rig)]  # ClassVar bounds are no fields
    known = set(fields)
    unknown = sorted(str(k) for k in set(data) - known)
    if unknown:
        raise GazeAugError(f"{at(unknown[0])}: unknown rig fields {unknown} (known: {sorted(known)})")
    missing = [k for k in fields if k not in _OPTIONAL_FIELDS and k not in data]
    if missing:  # a default would silently stand in for what the file meant to say (a truncated file)
        raise GazeAugError(
            f"{p}: a rig file must give every field but {', '.join(_OPTIONAL_FIELDS)}; missing {missing} "
            f"(see data_samples/rigs/ for complete files)"
        )
    data.setdefault("name", p.stem)
    for key, parse in (("targets", target_from_dict), ("planes", plane_from_dict)):
        items = data.get(key, [])
        if items is None:
            items = []
        if not isinstance(items, list):
            raise GazeAugError(f"{at(key)}: {key}: expected a list, got {type(items).__name__}")
        data[key] = tuple(parse(item, at((key, i))) for i, item in enumerate(items))
    try:
        return Rig(**_tupled(data))
    except GazeAugError as exc:
        named = [k for k in fields if f"{k}:" in str(exc) or f"{k} " in str(exc)]
        raise GazeAugError(f"{at(named[0]) if named else p}: {exc}") from exc
    except (TypeError, ValueError, OverflowError) as exc:  # a field of the wrong type or size
        raise GazeAugError(f"{p}: bad rig field value ({exc.__class__.__name__}: {exc})") from exc


def _tupled(data: dict[str, Any]) -> dict[str, Any]:
    """Rig fields with JSON/YAML lists made the tuples :class:`Rig` holds."""
    data = dict(data)
    for k in ("camera_position_mm", "image_size_wh"):
        if isinstance(data.get(k), list):
            data[k] = tuple(data[k])
    if isinstance(data.get("target_box_mm"), list):
        data["target_box_mm"] = tuple(tuple(c) for c in data["target_box_mm"])
    return data


def rig_from_dict(data: dict[str, Any]) -> Rig:
    """The rig that :meth:`Rig.as_dict` recorded (as an output's settings keep it).

    Raises:
        GazeAugError: not a recorded rig.
    """
    if not isinstance(data, dict):
        raise GazeAugError(f"rig: expected a mapping of rig fields, got {type(data).__name__}")
    d = dict(data)
    for key, parse in (("targets", target_from_dict), ("planes", plane_from_dict)):
        d[key] = tuple(parse(item, f"rig {key}[{i}]") for i, item in enumerate(d.get(key) or []))
    try:
        return Rig(**_tupled(d))
    except (TypeError, ValueError) as exc:
        raise GazeAugError(f"rig: bad recorded fields ({exc})") from exc


#: Rig fields a rig file may leave out: the name (the file's stem), and the scene (none).
_OPTIONAL_FIELDS = ("name", "targets", "planes")


def _yaml_lines(text: str) -> dict[Any, int]:
    """1-based line numbers of a YAML mapping's top-level keys (``key``) and list items (``(key, i)``)."""
    import yaml

    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return {}
    out: dict[Any, int] = {}
    if isinstance(root, yaml.MappingNode):
        for k, v in root.value:
            key = k.value
            if key in out:  # YAML keeps the last of a repeated key: a mistake that would pass unseen
                raise GazeAugError(
                    f"line {k.start_mark.line + 1}: the field {key!r} is given twice (first on line {out[key]})"
                )
            out[key] = k.start_mark.line + 1
            if isinstance(v, yaml.SequenceNode):
                for i, item in enumerate(v.value):
                    out[(key, i)] = item.start_mark.line + 1
    return out


def sampled_rotations(yaw_pitch_rad: ArrayLike) -> NDArray[np.float64]:
    """(K, 2) radians (yaw, pitch) -> (K, 3, 3) rotations ``R(y, p)``."""
    yp = np.asarray(yaw_pitch_rad, dtype=np.float64).reshape(-1, 2)
    return np.stack([rotation_from_yaw_pitch(y, p) for y, p in yp])
