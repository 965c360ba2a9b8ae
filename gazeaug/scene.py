"""What the user can look at in a rig: named targets (spheres, boxes) and planes, and where a gaze ray lands.

Everything here is in the rig frame (:class:`gazeaug.sampling.Rig`; the frame
is defined in :mod:`facemesh.conventions`): millimetres, origin between the
eyes of the user at rest, x toward the user's left, y down, z back into the
head, so what lies in front of the user has negative z.

- A **sphere target** (``centre_mm``, ``radius_mm``): an object, a button.
- A **box target** (``min_mm``, ``max_mm``): an axis-aligned box of the rig frame.
- A **plane** (``corner_mm``, ``edge1_mm``, ``edge2_mm``): the parallelogram
  ``corner + s edge1 + u edge2`` for ``0 <= s, u <= 1``: a table top, a screen.
  Planes give a point of gaze; they are never selected.

:meth:`Scene.look` casts a gaze ray: the **point of gaze** is its nearest
exact hit on a target or a plane; the **target looked at** is chosen with an
angular margin (gaze estimates are off by degrees): each target is inflated
by ``distance * tan(margin)`` (the sphere's radius, or every side of the box;
``distance`` from the ray's origin to the target's centre), and among the
inflated targets the ray hits, the one whose centre lies at the smallest angle
from the ray is looked at; a target grown over the ray's origin (the eyes) is
never looked at. With margin 0 the target is the nearest exact hit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import GazeAugError

__all__ = [
    "SphereTarget",
    "BoxTarget",
    "Plane",
    "Target",
    "Scene",
    "Look",
    "ray_sphere",
    "ray_box",
    "ray_parallelogram",
]

Vec3 = tuple[float, float, float]

#: Coordinates of a scene lie within this many millimetres of the eyes (100 m).
MAX_COORD_MM = 1e5


def _vec3(value: Any, what: str) -> Vec3:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise GazeAugError(f"{what}: expected three numbers (x, y, z) mm, got {value!r}") from exc
    if a.shape != (3,) or not np.isfinite(a).all() or np.abs(a).max() > MAX_COORD_MM:
        raise GazeAugError(
            f"{what}: expected three finite numbers (x, y, z) within +-{MAX_COORD_MM:g} mm, got {value!r}"
        )
    return (float(a[0]), float(a[1]), float(a[2]))


def _name(value: Any, what: str) -> str:
    if not isinstance(value, str) or not value.strip() or any(c in value for c in ",\n\r\"'") or len(value) > 100:
        raise GazeAugError(
            f"{what}: expected a name of 1-100 characters without commas, quotes or line breaks, got {value!r}"
        )
    return value


def _not_at_the_eyes(target: Any) -> None:
    if target.contains(np.zeros(3)):
        raise GazeAugError(f"target {target.name!r}: it holds the eyes (the rig frame's origin); targets lie in front")


@dataclass(frozen=True)
class SphereTarget:
    """A target that is a ball: ``centre_mm`` (3,) rig frame, mm; ``radius_mm`` > 0."""

    name: str
    centre_mm: Vec3
    radius_mm: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", _name(self.name, "target name"))
        object.__setattr__(self, "centre_mm", _vec3(self.centre_mm, f"target {self.name!r}: centre_mm"))
        r = self.radius_mm
        if isinstance(r, bool) or not isinstance(r, (int, float, np.integer, np.floating)) or not (0 < r < 1e6):
            raise GazeAugError(f"target {self.name!r}: radius_mm: expected a number > 0 mm, got {r!r}")
        object.__setattr__(self, "radius_mm", float(r))
        _not_at_the_eyes(self)

    @property
    def centre(self) -> NDArray[np.float64]:
        """(3,) float64, rig frame, mm."""
        return np.asarray(self.centre_mm)

    def hit(self, origin: NDArray[np.float64], direction: NDArray[np.float64], inflate_mm: float = 0.0) -> float | None:
        """Distance along the ray (mm) to the first hit of the ball grown by ``inflate_mm``, or None."""
        return ray_sphere(origin, direction, self.centre, self.radius_mm + inflate_mm)

    def contains(self, point: NDArray[np.float64], inflate_mm: float = 0.0) -> bool:
        """Whether ``point`` (3,) mm lies inside the ball grown by ``inflate_mm``."""
        return bool(np.linalg.norm(point - self.centre) < self.radius_mm + inflate_mm)

    def as_dict(self) -> dict[str, Any]:
        """The rig-file form."""
        return {"name": self.name, "centre_mm": list(self.centre_mm), "radius_mm": self.radius_mm}


@dataclass(frozen=True)
class BoxTarget:
    """A target that is an axis-aligned box of the rig frame: corners ``min_mm`` <= ``max_mm`` (mm)."""

    name: str
    min_mm: Vec3
    max_mm: Vec3

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", _name(self.name, "target name"))
        lo = _vec3(self.min_mm, f"target {self.name!r}: min_mm")
        hi = _vec3(self.max_mm, f"target {self.name!r}: max_mm")
        if any(a >= b for a, b in zip(lo, hi)):
            raise GazeAugError(f"target {self.name!r}: expected min_mm < max_mm on every axis, got {lo} and {hi}")
        object.__setattr__(self, "min_mm", lo)
        object.__setattr__(self, "max_mm", hi)
        _not_at_the_eyes(self)

    @property
    def centre(self) -> NDArray[np.float64]:
        """(3,) float64, rig frame, mm."""
        return (np.asarray(self.min_mm) + np.asarray(self.max_mm)) / 2

    def hit(self, origin: NDArray[np.float64], direction: NDArray[np.float64], inflate_mm: float = 0.0) -> float | None:
        """Distance along the ray (mm) to the first hit of the box grown by ``inflate_mm`` on every side, or None."""
        return ray_box(origin, direction, np.asarray(self.min_mm) - inflate_mm, np.asarray(self.max_mm) + inflate_mm)

    def contains(self, point: NDArray[np.float64], inflate_mm: float = 0.0) -> bool:
        """Whether ``point`` (3,) mm lies inside the box grown by ``inflate_mm`` on every side."""
        lo, hi = np.asarray(self.min_mm) - inflate_mm, np.asarray(self.max_mm) + inflate_mm
        return bool(np.all(point > lo) and np.all(point < hi))

    def as_dict(self) -> dict[str, Any]:
        """The rig-file form."""
        return {"name": self.name, "min_mm": list(self.min_mm), "max_mm": list(self.max_mm)}


Target = Union[SphereTarget, BoxTarget]


@dataclass(frozen=True)
class Plane:
    """A flat surface: the parallelogram ``corner_mm + s edge1_mm + u edge2_mm``, ``0 <= s, u <= 1`` (rig frame, mm)."""

    name: str
    corner_mm: Vec3
    edge1_mm: Vec3
    edge2_mm: Vec3

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", _name(self.name, "plane name"))
        for f in ("corner_mm", "edge1_mm", "edge2_mm"):
            object.__setattr__(self, f, _vec3(getattr(self, f), f"plane {self.name!r}: {f}"))
        e1, e2 = np.asarray(self.edge1_mm), np.asarray(self.edge2_mm)
        if np.linalg.norm(np.cross(e1, e2)) < 1e-6 * max(1.0, float(np.linalg.norm(e1) * np.linalg.norm(e2))):
            raise GazeAugError(f"plane {self.name!r}: edge1_mm and edge2_mm are parallel or zero; they span no plane")

    def hit(self, origin: NDArray[np.float64], direction: NDArray[np.float64]) -> float | None:
        """Distance along the ray (mm) to the parallelogram, or None."""
        return ray_parallelogram(
            origin, direction, np.asarray(self.corner_mm), np.asarray(self.edge1_mm), np.asarray(self.edge2_mm)
        )

    def as_dict(self) -> dict[str, Any]:
        """The rig-file form."""
        return {
            "name": self.name,
            "corner_mm": list(self.corner_mm),
            "edge1_mm": list(self.edge1_mm),
            "edge2_mm": list(self.edge2_mm),
        }


def ray_sphere(
    origin: NDArray[np.float64], direction: NDArray[np.float64], centre: NDArray[np.float64], radius: float
) -> float | None:
    """Distance ``t >= 0`` along a unit-direction ray to its first hit of a sphere, or None.

    Solves ``|o + t d - c| = r``: with ``b = d . (o - c)`` and ``q = |o - c|^2 - r^2``,
    ``t = -b - sqrt(b^2 - q)`` (``-b + sqrt(...)`` from inside).
    """
    oc = origin - centre
    b = float(direction @ oc)
    q = float(oc @ oc) - radius * radius
    disc = b * b - q
    if disc < 0:
        return None
    root = math.sqrt(disc)
    t = -b - root
    if t < 0:
        t = -b + root
    return t if t >= 0 else None


def ray_box(
    origin: NDArray[np.float64], direction: NDArray[np.float64], lo: NDArray[np.float64], hi: NDArray[np.float64]
) -> float | None:
    """Distance ``t >= 0`` along a ray to an axis-aligned box (slab method; 0 from inside), or None."""
    t_near, t_far = -math.inf, math.inf
    for k in range(3):
        d, o = float(direction[k]), float(origin[k])
        if d == 0.0:
            if o < lo[k] or o > hi[k]:
                return None
            continue
        a, b = (lo[k] - o) / d, (hi[k] - o) / d
        t_near, t_far = max(t_near, min(a, b)), min(t_far, max(a, b))
    if t_near > t_far or t_far < 0:
        return None
    return max(t_near, 0.0)


def ray_parallelogram(
    origin: NDArray[np.float64],
    direction: NDArray[np.float64],
    corner: NDArray[np.float64],
    edge1: NDArray[np.float64],
    edge2: NDArray[np.float64],
) -> float | None:
    """Distance ``t >= 0`` along a ray to the parallelogram ``corner + s edge1 + u edge2``, or None.

    The parallelogram holds the points with ``0 <= s, u <= 1``.
    """
    n = np.cross(edge1, edge2)
    denom = float(direction @ n)
    if abs(denom) < 1e-12 * float(np.linalg.norm(n)):
        return None  # parallel to the plane
    t = float((corner - origin) @ n) / denom
    if t < 0:
        return None
    w = origin + t * direction - corner
    g = np.array([[edge1 @ edge1, edge1 @ edge2], [edge1 @ edge2, edge2 @ edge2]])
    s, u = np.linalg.solve(g, np.array([w @ edge1, w @ edge2]))
    eps = 1e-9
    return t if (-eps <= s <= 1 + eps and -eps <= u <= 1 + eps) else None


@dataclass(frozen=True)
class Look:
    """Where one gaze ray lands (rig frame).

    Attributes:
        point_mm: (3,) float64, mm: the point of gaze, the ray's nearest exact hit on a target or
            a plane; NaN when it hits nothing.
        surface: the name of what ``point_mm`` lies on (a target or a plane), or None.
        target: the target looked at (with the angular margin), or None.
    """

    point_mm: NDArray[np.float64]
    surface: str | None
    target: str | None


@dataclass(frozen=True)
class Scene:
    """The targets and planes of a rig (rig frame, mm); names are unique across both."""

    targets: tuple[Target, ...] = ()
    planes: tuple[Plane, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "targets", tuple(self.targets))
        object.__setattr__(self, "planes", tuple(self.planes))
        for t in self.targets:
            if not isinstance(t, (SphereTarget, BoxTarget)):
                raise GazeAugError(f"targets: expected SphereTarget or BoxTarget, got {type(t).__name__}")
        for p in self.planes:
            if not isinstance(p, Plane):
                raise GazeAugError(f"planes: expected Plane, got {type(p).__name__}")
        names = [t.name for t in self.targets] + [p.name for p in self.planes]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise GazeAugError(f"targets and planes need unique names; repeated: {dup}")

    def __bool__(self) -> bool:
        return bool(self.targets or self.planes)

    def look(self, origin_mm: ArrayLike, direction: ArrayLike, margin_deg: float = 0.0) -> Look:
        """Cast the gaze ray ``origin_mm + t direction`` (rig frame; any non-zero direction length).

        Returns the point of gaze and the target looked at (module docstring for the margin).
        """
        o = np.asarray(origin_mm, dtype=np.float64)
        d = np.asarray(direction, dtype=np.float64)
        norm = float(np.linalg.norm(d))
        if not (np.isfinite(o).all() and np.isfinite(d).all() and norm > 0):
            return Look(np.full(3, np.nan), None, None)
        d = d / norm
        best_t, surface = math.inf, None
        for thing in (*self.targets, *self.planes):
            t = thing.hit(o, d)
            if t is not None and t < best_t:
                best_t, surface = t, thing.name
        point = o + best_t * d if surface is not None else np.full(3, np.nan)
        tan_m = math.tan(math.radians(margin_deg))
        target, best_key = None, math.inf
        for tg in self.targets:
            to_c = tg.centre - o
            dist = float(np.linalg.norm(to_c))
            grow = dist * tan_m
            t_hit = None if tg.contains(o, grow) else tg.hit(o, d, grow)  # grown over the eyes: catches every gaze
            if t_hit is None:
                continue
            if margin_deg == 0.0:  # exact: the nearest hit
                key = t_hit
            else:  # the smallest angle between the ray and the direction to the centre
                key = math.acos(max(-1.0, min(1.0, float(to_c @ d) / dist))) if dist > 0 else 0.0
            if key < best_key:
                target, best_key = tg.name, key
        return Look(point, surface, target)

    def as_dict(self) -> dict[str, Any]:
        """The rig-file form (``targets`` and ``planes`` lists)."""
        return {"targets": [t.as_dict() for t in self.targets], "planes": [p.as_dict() for p in self.planes]}


def target_from_dict(item: Any, where: str) -> Target:
    """A target from its rig-file mapping.

    A sphere has ``name``, ``centre_mm`` and ``radius_mm``; a box ``name``, ``min_mm`` and ``max_mm``.
    """
    if not isinstance(item, dict):
        raise GazeAugError(
            f"{where}: expected a mapping with name and centre_mm/radius_mm or min_mm/max_mm, got {item!r}"
        )
    keys = set(item)
    try:
        if keys == {"name", "centre_mm", "radius_mm"}:
            return SphereTarget(item["name"], item["centre_mm"], item["radius_mm"])
        if keys == {"name", "min_mm", "max_mm"}:
            return BoxTarget(item["name"], item["min_mm"], item["max_mm"])
    except GazeAugError as exc:
        raise GazeAugError(f"{where}: {exc}") from exc
    raise GazeAugError(
        f"{where}: a target has the keys name, centre_mm, radius_mm (a sphere) or name, min_mm, max_mm (a box); "
        f"got {sorted(map(str, keys))}"
    )


def plane_from_dict(item: Any, where: str) -> Plane:
    """A plane from its rig-file mapping (``name``, ``corner_mm``, ``edge1_mm``, ``edge2_mm``)."""
    want = {"name", "corner_mm", "edge1_mm", "edge2_mm"}
    if not isinstance(item, dict) or set(item) != want:
        got = sorted(map(str, item)) if isinstance(item, dict) else repr(item)
        raise GazeAugError(f"{where}: a plane has the keys {sorted(want)}; got {got}")
    try:
        return Plane(item["name"], item["corner_mm"], item["edge1_mm"], item["edge2_mm"])
    except GazeAugError as exc:
        raise GazeAugError(f"{where}: {exc}") from exc
