"""Virtual scenes and point collision detection (thesis section 2.2.1).

The user's hand is mapped into the scene as a point proxy. Each shape reports
a *signed penetration depth* ``d`` (positive inside the object, negative
outside: minus the distance to the surface) and the outward surface normal
``n`` (unit 3-vector). Proportional feedback is then ``F = k * d * n`` while
``d > 0`` (eq. 2.1, ``x = -d n``). With several objects the deepest
penetration wins (largest ``d``).

The 1-DOF device maps its handle position to the proxy ``(0, 0, z)``. The 1-D
queries are plain scalar functions (``wall_1d`` ... ``box_1d``) that the shapes
call and that ``renderer.law`` compiles into the servo law.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

Vec3 = tuple[float, float, float]


def _vec3(value: Any, where: str) -> Vec3:
    if not (isinstance(value, (list, tuple)) and len(value) == 3):
        raise ValueError(f"{where} must be a list of 3 numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{where} must contain finite numbers, got {value!r}")
        out.append(float(v))
    return (out[0], out[1], out[2])


def _finite(value: Any, where: str, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{where} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise ValueError(f"{where} must be > 0, got {value!r}")
    return float(value)


# ---- 1-DOF penetration of each shape: plain scalar functions of the shape's numbers and the proxy
# height z. The shapes' penetration_1d methods call them, and renderer.law compiles the same functions
# into the servo law (one source for the collision of the Python loop and the compiled loop).
SHAPE_CODES = {"wall": 1, "plane": 2, "sphere": 3, "box": 4}


def wall_1d(height_m, z):
    """Signed depth (m) and normal z component of the proxy (0, 0, z) under a horizontal wall."""
    return height_m - z, 1.0


def plane_1d(qx, qy, qz, nx, ny, nz, z):
    """Signed depth and normal z component behind the plane through q with unit normal n."""
    return qx * nx + qy * ny + (qz - z) * nz, nz


def sphere_1d(cx, cy, cz, r, z):
    """Signed depth and normal z component for a sphere of centre c and radius r (+z at the centre)."""
    dz = z - cz
    dist = math.sqrt(cx * cx + cy * cy + dz * dz)
    if dist == 0.0:
        return r, 1.0
    return r - dist, dz / dist


def box_1d(cx, cy, cz, hx, hy, hz, z):
    """Signed depth and normal z component for an axis-aligned box (centre c, half extents h)."""
    qx = abs(cx) - hx
    qy = abs(cy) - hy
    dz = z - cz
    qz = abs(dz) - hz
    sz = 1.0 if dz >= 0.0 else -1.0
    if qx <= 0.0 and qy <= 0.0 and qz <= 0.0:
        # nearest face; ties go to x, then y (as in Box.penetration())
        if qx >= qy and qx >= qz:
            return -qx, 0.0
        if qy >= qz:
            return -qy, 0.0
        return -qz, sz
    ox = qx if qx > 0.0 else 0.0
    oy = qy if qy > 0.0 else 0.0
    oz = qz if qz > 0.0 else 0.0
    dist = math.sqrt(ox * ox + oy * oy + oz * oz)
    return -dist, sz * oz / dist


@dataclass(frozen=True)
class Wall:
    """Horizontal 1-DOF wall: solid below ``height_m``, normal +z (a tap comes from above)."""

    height_m: float = 0.0
    shape = "wall"

    def penetration(self, p: Vec3) -> tuple[float, Vec3]:
        """Signed depth ``height_m - z`` (m) and normal (0, 0, 1)."""
        return self.height_m - p[2], (0.0, 0.0, 1.0)

    def penetration_1d(self, z: float) -> tuple[float, float]:
        """Signed depth and normal z component for the proxy (0, 0, z)."""
        return wall_1d(self.height_m, z)

    def numbers(self) -> tuple[float, ...]:
        """The shape's numbers in the order of :func:`wall_1d`."""
        return (self.height_m,)


@dataclass(frozen=True)
class Plane:
    """Half-space behind a plane through ``point_m`` with outward ``normal`` (normalised on creation)."""

    point_m: Vec3 = (0.0, 0.0, 0.0)
    normal: Vec3 = (0.0, 0.0, 1.0)
    shape = "plane"

    def __post_init__(self) -> None:
        n = math.hypot(*self.normal)  # no underflow: a normal of 1e-200 still has a direction
        if not n > 0:
            raise ValueError("plane normal must be a non-zero vector")
        object.__setattr__(self, "normal", (self.normal[0] / n, self.normal[1] / n, self.normal[2] / n))

    def penetration(self, p: Vec3) -> tuple[float, Vec3]:
        """Signed depth ``(point - p) . n`` (m) and the plane normal."""
        q, n = self.point_m, self.normal
        return (q[0] - p[0]) * n[0] + (q[1] - p[1]) * n[1] + (q[2] - p[2]) * n[2], n

    def penetration_1d(self, z: float) -> tuple[float, float]:
        """Signed depth and normal z component for the proxy (0, 0, z)."""
        q, n = self.point_m, self.normal
        return plane_1d(q[0], q[1], q[2], n[0], n[1], n[2], z)

    def numbers(self) -> tuple[float, ...]:
        """The shape's numbers in the order of :func:`plane_1d`."""
        return (*self.point_m, *self.normal)


@dataclass(frozen=True)
class Sphere:
    """Solid sphere; the normal points from the centre to the proxy."""

    center_m: Vec3 = (0.0, 0.0, 0.0)
    radius_m: float = 0.05
    shape = "sphere"

    def penetration(self, p: Vec3) -> tuple[float, Vec3]:
        """Signed depth ``r - |p - c|`` (m) and the radial unit normal (+z at the exact centre)."""
        dx, dy, dz = p[0] - self.center_m[0], p[1] - self.center_m[1], p[2] - self.center_m[2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dist == 0.0:
            return self.radius_m, (0.0, 0.0, 1.0)
        return self.radius_m - dist, (dx / dist, dy / dist, dz / dist)

    def penetration_1d(self, z: float) -> tuple[float, float]:
        """Signed depth and normal z component for the proxy (0, 0, z) (same as :meth:`penetration`)."""
        c = self.center_m
        return sphere_1d(c[0], c[1], c[2], self.radius_m, z)

    def numbers(self) -> tuple[float, ...]:
        """The shape's numbers in the order of :func:`sphere_1d`."""
        return (*self.center_m, self.radius_m)


@dataclass(frozen=True)
class Box:
    """Axis-aligned solid box of half extents ``half_extents_m`` around ``center_m``.

    Inside, the depth is the distance to the nearest face and the normal is
    that face's outward normal (the classic minimum-penetration direction).
    Outside, the depth is minus the Euclidean distance to the box and the
    normal points from the closest box point to the proxy.
    """

    center_m: Vec3 = (0.0, 0.0, 0.0)
    half_extents_m: Vec3 = (0.05, 0.05, 0.05)
    shape = "box"

    def penetration(self, p: Vec3) -> tuple[float, Vec3]:
        """Depth (m, > 0 inside) of point ``p`` below the nearest face of the box, and that face's outward normal."""
        d = [p[i] - self.center_m[i] for i in range(3)]
        q = [abs(d[i]) - self.half_extents_m[i] for i in range(3)]
        if q[0] <= 0.0 and q[1] <= 0.0 and q[2] <= 0.0:
            axis = max(range(3), key=lambda i: q[i])  # the face closest to the proxy
            normal = [0.0, 0.0, 0.0]
            normal[axis] = 1.0 if d[axis] >= 0.0 else -1.0
            return -q[axis], (normal[0], normal[1], normal[2])
        out = [max(qi, 0.0) * (1.0 if di >= 0.0 else -1.0) for qi, di in zip(q, d)]
        dist = math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2)
        return -dist, (out[0] / dist, out[1] / dist, out[2] / dist)

    def penetration_1d(self, z: float) -> tuple[float, float]:
        """Signed depth and normal z component for the proxy (0, 0, z) (same as :meth:`penetration`)."""
        c, h = self.center_m, self.half_extents_m
        return box_1d(c[0], c[1], c[2], h[0], h[1], h[2], z)

    def numbers(self) -> tuple[float, ...]:
        """The shape's numbers in the order of :func:`box_1d`."""
        return (*self.center_m, *self.half_extents_m)


SHAPES: dict[str, tuple[type, dict[str, str]]] = {
    # shape name -> (class, {key: kind}); kind "vec3" | "float" | "positive" | "vec3+"
    "wall": (Wall, {"height_m": "float"}),
    "plane": (Plane, {"point_m": "vec3", "normal": "vec3"}),
    "sphere": (Sphere, {"center_m": "vec3", "radius_m": "positive"}),
    "box": (Box, {"center_m": "vec3", "half_extents_m": "vec3+"}),
}


@dataclass(frozen=True)
class Scene:
    """A set of solid objects; :meth:`penetration` returns the deepest one's depth and normal."""

    objects: tuple = (Wall(0.0),)

    def __post_init__(self) -> None:
        if not self.objects:
            raise ValueError("scene.objects must contain at least one object")
        object.__setattr__(self, "_fns_1d", tuple(obj.penetration_1d for obj in self.objects))

    @property
    def single_wall(self) -> Wall | None:
        """The wall if the scene is exactly one :class:`Wall` (the servo loop's fast path), else None."""
        if len(self.objects) == 1 and isinstance(self.objects[0], Wall):
            return self.objects[0]
        return None

    def penetration(self, p: Vec3) -> tuple[float, Vec3]:
        """Deepest signed penetration (m) over all objects and its outward normal."""
        best_d, best_n = -math.inf, (0.0, 0.0, 1.0)
        for obj in self.objects:
            d, n = obj.penetration(p)
            if d > best_d:
                best_d, best_n = d, n
        return best_d, best_n

    def penetration_1d(self, z_m: float) -> tuple[float, float]:
        """Deepest signed penetration (m) of the 1-DOF proxy (0, 0, z) and the normal's z component.

        Scalar fast path of :meth:`penetration` (no tuples built per object) for the servo loop.
        """
        best_d = -math.inf
        best_nz = 1.0
        for fn in self._fns_1d:
            d, nz = fn(z_m)
            if d > best_d:
                best_d = d
                best_nz = nz
        return best_d, best_nz

    def to_dict(self) -> dict:
        """The scene as plain data (``{"objects": [...]}``), as :func:`parse_scene` reads it."""
        out = []
        for obj in self.objects:
            entry = {"shape": obj.shape}
            for key in SHAPES[obj.shape][1]:
                value = getattr(obj, key)
                entry[key] = list(value) if isinstance(value, tuple) else value
            out.append(entry)
        return {"objects": out}


def parse_scene(data: Mapping[str, Any], where: str = "scene") -> Scene:
    """Build a :class:`Scene` from ``{"objects": [{"shape": ..., ...}, ...]}``.

    Raises
    ------
    ValueError
        Naming ``where`` and the offending object index/key for unknown keys
        or shapes, missing ``shape``, non-finite or non-positive sizes.
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"{where} must be a table with an 'objects' list")
    unknown = set(data) - {"objects"}
    if unknown:
        raise ValueError(f"{where}: unknown key {sorted(unknown)[0]!r} (allowed: 'objects')")
    objects = data.get("objects")
    if not isinstance(objects, list) or not objects:
        raise ValueError(f"{where}.objects must be a non-empty list of objects")
    built = []
    for idx, raw in enumerate(objects):
        here = f"{where}.objects[{idx}]"
        if not isinstance(raw, Mapping):
            raise ValueError(f"{here} must be a table")
        shape = raw.get("shape")
        if not isinstance(shape, str) or shape not in SHAPES:  # a list or table is unhashable: no raw TypeError
            raise ValueError(f"{here}.shape: unknown shape {shape!r} (known: {', '.join(SHAPES)})")
        cls, keys = SHAPES[shape]
        kwargs = {}
        for key, value in raw.items():
            if key == "shape":
                continue
            if key not in keys:
                raise ValueError(f"{here}: unknown key {key!r} for shape {shape!r} (allowed: {', '.join(keys)})")
            kind = keys[key]
            if kind == "float":
                kwargs[key] = _finite(value, f"{here}.{key}")
            elif kind == "positive":
                kwargs[key] = _finite(value, f"{here}.{key}", positive=True)
            else:
                vec = _vec3(value, f"{here}.{key}")
                if kind == "vec3+" and min(vec) <= 0:
                    raise ValueError(f"{here}.{key} must be all > 0, got {list(vec)}")
                if key == "normal" and not math.hypot(*vec) > 0:
                    raise ValueError(f"{here}.normal must be a non-zero vector")
                kwargs[key] = vec
        built.append(cls(**kwargs))
    return Scene(tuple(built))
