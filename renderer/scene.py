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
import os
from dataclasses import dataclass, field
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
    props: "SurfaceProps | None" = None
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
    props: "SurfaceProps | None" = None
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
    props: "SurfaceProps | None" = None
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
    props: "SurfaceProps | None" = None
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


@dataclass(frozen=True)
class Mesh:
    """A closed triangle mesh read from an OBJ or STL file (3-D rendering only; ``renderer.mesh`` loads and checks it).

    ``path`` is resolved against the scene file's folder; the file's coordinates are multiplied by
    ``scale`` (e.g. 0.001 for a file in millimetres) and shifted by ``offset_m`` (device frame, m).
    """

    path: str = ""
    scale: float = 1.0
    offset_m: Vec3 = (0.0, 0.0, 0.0)
    props: "SurfaceProps | None" = None
    shape = "mesh"

    def penetration_1d(self, z: float) -> tuple[float, float]:
        """Not defined: a mesh renders only on the 3-D renderer (``renderer.loop3``)."""
        raise ValueError(f"mesh {self.path!r}: meshes render only with the 3-D renderer")

    def numbers(self) -> tuple[float, ...]:
        """Not defined for the 1-DOF law (see :meth:`penetration_1d`)."""
        raise ValueError(f"mesh {self.path!r}: meshes render only with the 3-D renderer")


#: transients a scene object may name (``transient = "..."``); an HFAM object also names its ``library``
OBJECT_TRANSIENTS = ("none", "pulse", "sinusoid", "hfam")


@dataclass(frozen=True)
class SurfaceProps:
    """How one object of a 3-D scene feels: its own stiffness, friction and contact transient.

    Attributes
    ----------
    name : str
        The object's name (in errors, events and a study's trial table); default ``<shape><index>``.
    stiffness_N_m : float or None
        Its wall stiffness (N/m); None: the config's ``stiffness_N_m``.
    mu_static, mu_dynamic : float
        Coulomb friction coefficients (static >= dynamic >= 0) of the proxy on it (stick-slip).
    transient : str or None
        ``none``, ``pulse``, ``sinusoid`` or ``hfam`` (Table 4.1's parameters); None: the run's transient.
    library : str or None
        The HFAM library (.npz) of ``transient = "hfam"``.
    sample : str or None
        A virtual sample of the catalog (``stimuli.load_catalog``, Table 4.1: ``pulse_firm``, ...): its
        stiffness and transient, unless given here.
    force_shading : bool
        Meshes: the force and the transient along the normal interpolated from the vertex normals.
    """

    name: str = ""
    stiffness_N_m: float | None = None
    mu_static: float = 0.0
    mu_dynamic: float = 0.0
    transient: str | None = None
    library: str | None = None
    sample: str | None = None
    force_shading: bool = False

    def is_default(self) -> bool:
        """True when nothing here differs from a 1-DOF scene's object."""
        return self == SurfaceProps(name=self.name)


#: keys every object may carry besides its shape's own (``SurfaceProps``)
PROP_KEYS = {"name": "str", "stiffness_N_m": "nonneg", "mu_static": "nonneg", "mu_dynamic": "nonneg",
             "transient": "str", "library": "str", "sample": "str", "force_shading": "bool"}

SHAPES: dict[str, tuple[type, dict[str, str]]] = {
    # shape name -> (class, {key: kind}); kind "vec3" | "float" | "positive" | "vec3+" | "str"
    "wall": (Wall, {"height_m": "float"}),
    "plane": (Plane, {"point_m": "vec3", "normal": "vec3"}),
    "sphere": (Sphere, {"center_m": "vec3", "radius_m": "positive"}),
    "box": (Box, {"center_m": "vec3", "half_extents_m": "vec3+"}),
    "mesh": (Mesh, {"path": "str", "scale": "positive", "offset_m": "vec3"}),
}


@dataclass(frozen=True)
class Scene:
    """A set of solid objects; :meth:`penetration` returns the deepest one's depth and normal."""

    objects: tuple = (Wall(0.0),)
    source: str = field(default="scene", compare=False)
    base_dir: str = field(default=".", compare=False)

    def __post_init__(self) -> None:
        if not self.objects:
            raise ValueError("scene.objects must contain at least one object")
        object.__setattr__(self, "_fns_1d", tuple(obj.penetration_1d for obj in self.objects))

    @property
    def needs_3d(self) -> bool:
        """True if the scene needs the 3-D renderer (``renderer.loop3``): a mesh, or an object with its own
        stiffness, friction, transient or sample."""
        return any(isinstance(o, Mesh) or (o.props is not None and not o.props.is_default()) for o in self.objects)

    def object_name(self, index: int) -> str:
        """Object ``index``'s name (its ``name`` key, else ``<shape><index>``)."""
        obj = self.objects[index]
        if obj.props is not None and obj.props.name:
            return obj.props.name
        return f"{obj.shape}{index}"

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
            if obj.props is not None:
                for key in PROP_KEYS:
                    value = getattr(obj.props, key)
                    if value != getattr(SurfaceProps(), key):
                        entry[key] = value
            out.append(entry)
        return {"objects": out}


def _prop(value: Any, kind: str, where: str):
    if kind == "str":
        if not isinstance(value, str) or not value:
            raise ValueError(f"{where} must be a non-empty text, got {value!r}")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"{where} must be true or false, got {value!r}")
        return value
    v = _finite(value, where)
    if v < 0:
        raise ValueError(f"{where} must be >= 0, got {value!r}")
    return v


def parse_scene(data: Mapping[str, Any], where: str = "scene", base_dir: str = ".") -> Scene:
    """Build a :class:`Scene` from ``{"objects": [{"shape": ..., ...}, ...]}``.

    Besides its shape's keys every object may carry :class:`SurfaceProps`' keys (``name``,
    ``stiffness_N_m``, ``mu_static``, ``mu_dynamic``, ``transient``, ``library``, ``sample``,
    ``force_shading``); a mesh's ``path`` and an HFAM ``library`` are resolved against ``base_dir``.

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
        props = {}
        for key, value in raw.items():
            if key == "shape":
                continue
            if key in PROP_KEYS:
                props[key] = _prop(value, PROP_KEYS[key], f"{here}.{key}")
                continue
            if key not in keys:
                raise ValueError(f"{here}: unknown key {key!r} for shape {shape!r} (allowed: "
                                 f"{', '.join([*keys, *PROP_KEYS])})")
            kind = keys[key]
            if kind == "str":
                kwargs[key] = _prop(value, "str", f"{here}.{key}")
            elif kind == "float":
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
        if shape == "mesh" and "path" not in kwargs:
            raise ValueError(f"{here}: a mesh needs its 'path' (an OBJ or STL file)")
        if props:
            mu_s, mu_d = props.get("mu_static", 0.0), props.get("mu_dynamic", 0.0)
            if mu_d > mu_s:
                raise ValueError(f"{here}: mu_dynamic={mu_d:g} exceeds mu_static={mu_s:g} (Coulomb friction: "
                                 "static >= dynamic)")
            tr = props.get("transient")
            if tr is not None and tr not in OBJECT_TRANSIENTS:
                raise ValueError(f"{here}.transient: unknown transient {tr!r} (known: {', '.join(OBJECT_TRANSIENTS)})")
            if tr == "hfam" and "library" not in props:
                raise ValueError(f"{here}: transient 'hfam' needs its 'library' (an HFAM library .npz)")
            if "library" in props:
                props["library"] = os.path.join(base_dir, props["library"])
            kwargs["props"] = SurfaceProps(**props)
        if shape == "mesh":
            kwargs["path"] = os.path.join(base_dir, kwargs["path"])
        built.append(cls(**kwargs))
    return Scene(tuple(built), source=where, base_dir=base_dir)
