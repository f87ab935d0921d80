"""A scene compiled for the 3-D proxy (``renderer.proxy``): meshes read and checked, BVHs built, arrays packed.

Mesh files are read with trimesh (OBJ, STL; ``renderer.meshfile``, imported only for a scene that has
one) and refused when empty, not watertight (non-manifold: an edge not shared by exactly two faces, or
inconsistent winding) or with a degenerate triangle (area below ``meshfile.DEGENERATE_AREA_M2``); boxes are built
here (trimesh's box, ``tests/renderer/test_proxy.py`` checks them against it); every object must fit inside
the device's workspace and be no stiffer than the device renders stably. Each refusal is a ``ValueError`` naming the scene file and the object (the
dispatcher prints it as one ``error:`` line); nothing reaches a motor, since this runs before the loop.

Arrays (float64, read by the compiled proxy):

* ``obj`` (n, ``OBJ_W``): kind (``K_PLANE``, ``K_SPHERE``, ``K_MESH``), stiffness (N/m), mu_static,
  mu_dynamic, force shading (0/1), then the shape's numbers: a plane's point and unit normal, a sphere's
  centre and radius, a mesh's first node and first triangle in ``node`` and ``tri``;
* ``tri`` (T, 21): per triangle its first vertex, its two edges, its unit normal and its three vertex
  normals (force shading), all meshes one after the other, in BVH order;
* ``node`` (N, 8): per BVH node its box (min, max); an inner node's two children (absolute indices), a
  leaf's ``-(first triangle + 1)`` and count.

Boxes become 12-triangle meshes, walls planes with normal +z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .scene import Box, Plane, Scene, Sphere, Wall

K_PLANE, K_SPHERE, K_MESH = 1.0, 2.0, 3.0
OBJ_W = 12
(O_KIND, O_K, O_MUS, O_MUD, O_SHADE, O_A0, O_A1, O_A2, O_A3, O_A4, O_A5) = range(11)
#: triangles per BVH leaf
LEAF_SIZE = 4
#: the deepest BVH the proxy's traversal stack holds
STACK_DEPTH = 64


@dataclass
class PackedScene:
    """The arrays of the module doc, plus per-object names, transients and bounds."""

    obj: np.ndarray
    tri: np.ndarray
    node: np.ndarray
    names: list
    props: list
    bounds: list


#: trimesh's unit box (``trimesh.creation.box``): corners, triangles (outward winding), face normals
_BOX_CORNERS = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 0], [0, 1, 1], [1, 0, 0], [1, 0, 1], [1, 1, 0], [1, 1, 1]],
                        dtype=np.float64)
_BOX_FACES = np.array([[1, 3, 0], [4, 1, 0], [0, 3, 2], [2, 4, 0], [1, 7, 3], [5, 1, 4], [5, 7, 1], [3, 7, 2],
                       [6, 4, 2], [2, 7, 6], [6, 5, 4], [7, 5, 6]])
_BOX_NORMALS = np.array([[-1, 0, 0], [0, -1, 0], [-1, 0, 0], [0, 0, -1], [0, 0, 1], [0, -1, 0], [0, 0, 1], [0, 1, 0],
                         [0, 0, -1], [0, 1, 0], [1, 0, 0], [1, 0, 0]], dtype=np.float64)


def box_arrays(box: Box) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A box as 12 triangles, as trimesh builds it (``trimesh.creation.box`` then translated).

    Returns
    -------
    tri : ndarray (12, 3, 3)
        Triangle corners (m).
    face_normals : ndarray (12, 3)
        Outward unit normals.
    vertex_normals : ndarray (12, 3, 3)
        Each triangle's corners' normals (the mean of the three faces meeting there, unit length).
    """
    vertices = (_BOX_CORNERS - 0.5) * (2.0 * np.asarray(box.half_extents_m, float)) + np.asarray(box.center_m, float)
    corner_normals = (2.0 * _BOX_CORNERS - 1.0) / math.sqrt(3.0)
    return vertices[_BOX_FACES], _BOX_NORMALS.copy(), corner_normals[_BOX_FACES]


def build_bvh(tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A bounding-volume hierarchy over triangles ``tris`` (T, 3, 3): median splits on the longest axis.

    Returns
    -------
    node : ndarray (N, 8)
        Boxes and children as in the module doc (indices relative to this BVH).
    order : ndarray of int (T,)
        The triangles in leaf order.
    """
    lo = tris.min(axis=1)
    hi = tris.max(axis=1)
    cen = tris.mean(axis=1)
    nodes = []
    order = []
    stack = [(np.arange(len(tris)), -1, 0)]
    while stack:
        idx, parent, side = stack.pop()
        me = len(nodes)
        box = np.concatenate([lo[idx].min(axis=0), hi[idx].max(axis=0)])
        nodes.append([*box, 0.0, 0.0])
        if parent >= 0:
            nodes[parent][6 + side] = me
        if len(idx) <= LEAF_SIZE:
            nodes[me][6] = -(len(order) + 1)
            nodes[me][7] = len(idx)
            order.extend(idx.tolist())
            continue
        c = cen[idx]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        srt = idx[np.argsort(c[:, axis], kind="stable")]
        half = len(srt) // 2
        stack.append((srt[half:], me, 1))
        stack.append((srt[:half], me, 0))
    return np.asarray(nodes, float), np.asarray(order, int)


def _depth(node: np.ndarray, i: int = 0) -> int:
    d, stack = 0, [(i, 1)]
    while stack:
        j, k = stack.pop()
        d = max(d, k)
        if node[j, 6] >= 0:
            stack += [(int(node[j, 6]), k + 1), (int(node[j, 7]), k + 1)]
    return d


def pack_scene(scene: Scene, default_k_N_m: float, specs=None, shading_default: bool = False) -> PackedScene:
    """Compile ``scene`` for the proxy: read and check meshes, build their BVHs, pack the arrays.

    Parameters
    ----------
    scene : renderer.scene.Scene
    default_k_N_m : float
        Stiffness of objects that name none (the config's ``stiffness_N_m``).
    specs : devices.base.DeviceSpecs or None
        The device's: objects outside its workspace, or stiffer than its stable bound, are refused.

    Raises
    ------
    ValueError
        Naming the scene file and the object (module doc).
    """
    n = len(scene.objects)
    obj = np.zeros((n, OBJ_W))
    tris_all, nodes_all, names, props_all, bounds = [], [], [], [], []
    t0 = n0 = 0
    for j, o in enumerate(scene.objects):
        name = scene.object_name(j)
        where = f"{scene.source}.objects[{j}] ({name})"
        pr = o.props
        k = pr.stiffness_N_m if pr is not None and pr.stiffness_N_m is not None else default_k_N_m
        if pr is not None and pr.sample and pr.stiffness_N_m is None:
            k = None   # the sample's stiffness, filled in by the loop from the catalog
        obj[j, O_K] = -1.0 if k is None else k
        obj[j, O_MUS] = pr.mu_static if pr else 0.0
        obj[j, O_MUD] = pr.mu_dynamic if pr else 0.0
        obj[j, O_SHADE] = 1.0 if (pr.force_shading if pr else shading_default) else 0.0
        if isinstance(o, Wall):
            obj[j, O_KIND] = K_PLANE
            obj[j, O_A0:O_A0 + 6] = (0.0, 0.0, o.height_m, 0.0, 0.0, 1.0)
            bounds.append(None)
        elif isinstance(o, Plane):
            obj[j, O_KIND] = K_PLANE
            obj[j, O_A0:O_A0 + 6] = (*o.point_m, *o.normal)
            bounds.append(None)
        elif isinstance(o, Sphere):
            obj[j, O_KIND] = K_SPHERE
            obj[j, O_A0:O_A0 + 4] = (*o.center_m, o.radius_m)
            c, r = np.asarray(o.center_m), o.radius_m
            bounds.append((c - r, c + r))
        else:
            if isinstance(o, Box):
                tri, fn, vn = box_arrays(o)
            else:
                from .meshfile import mesh_arrays  # deferred: trimesh and scipy, 0.4 s CPU that scenes without a mesh file never pay

                tri, fn, vn = mesh_arrays(o, where)
            node, order = build_bvh(tri)
            if _depth(node) >= STACK_DEPTH:
                raise ValueError(f"{where}: mesh too deep for the proxy's BVH stack ({len(tri)} triangles)")
            tri, fn, vn = tri[order], fn[order], vn[order]
            packed = np.empty((len(tri), 21))
            packed[:, 0:3] = tri[:, 0]
            packed[:, 3:6] = tri[:, 1] - tri[:, 0]
            packed[:, 6:9] = tri[:, 2] - tri[:, 0]
            packed[:, 9:12] = fn
            packed[:, 12:21] = vn.reshape(-1, 9)
            nn = np.linalg.norm(fn, axis=1)
            if not np.all(np.abs(nn - 1.0) < 1e-6):
                bad = int(np.flatnonzero(~(np.abs(nn - 1.0) < 1e-6))[0])
                raise ValueError(f"{where}: triangle {bad} has a normal of zero length")
            # absolute indices into the concatenated arrays
            node = node.copy()
            inner = node[:, 6] >= 0
            node[inner, 6:8] += n0
            node[~inner, 6] -= t0
            obj[j, O_KIND] = K_MESH
            obj[j, O_A0] = n0
            obj[j, O_A1] = t0
            tris_all.append(packed)
            nodes_all.append(node)
            t0 += len(tri)
            n0 += len(node)
            bounds.append((tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)))
        if specs is not None:
            if k is not None and k > specs.max_stiffness_N_m:
                raise ValueError(f"{where}: stiffness {k:g} N/m is above the device's stable bound "
                                 f"{specs.max_stiffness_N_m:g} N/m")
            b = bounds[-1]
            if b is not None and specs.axes == 3:
                lo, hi = np.asarray(specs.workspace_min_m), np.asarray(specs.workspace_max_m)
                if np.any(b[0] < lo - 1e-12) or np.any(b[1] > hi + 1e-12):
                    raise ValueError(f"{where}: the object spans {np.round(b[0], 4).tolist()} .. "
                                     f"{np.round(b[1], 4).tolist()} m, beyond the device's workspace "
                                     f"{list(lo)} .. {list(hi)} m")
        names.append(name)
        props_all.append(pr)
    tri = np.concatenate(tris_all) if tris_all else np.zeros((1, 21))
    node = np.concatenate(nodes_all) if nodes_all else np.zeros((1, 8))
    return PackedScene(obj=np.ascontiguousarray(obj), tri=np.ascontiguousarray(tri),
                       node=np.ascontiguousarray(node), names=names, props=props_all, bounds=bounds)


def signed_depth(packed: PackedScene, j: int, p) -> float:
    """Penetration (m, > 0 inside) of point ``p`` into object ``j``: exact for planes and spheres, for a mesh
    (convex or not) minus its signed distance (trimesh's closest point and winding; tests only)."""
    o = packed.obj[j]
    p = np.asarray(p, float)
    if o[O_KIND] == K_PLANE:
        return float(np.dot(o[O_A0:O_A0 + 3] - p, o[O_A0 + 3:O_A0 + 6]))
    if o[O_KIND] == K_SPHERE:
        return float(o[O_A0 + 3] - math.dist(p, o[O_A0:O_A0 + 3]))
    raise ValueError("signed_depth: meshes are tested with convex_depth")


def convex_depth(packed: PackedScene, j: int, pts: np.ndarray) -> np.ndarray:
    """Penetration (m) of points ``pts`` (n, 3) into a *convex* mesh object ``j``: the smallest distance
    behind its face planes (> 0 inside, <= 0 outside)."""
    n0 = int(packed.obj[j][O_A0])
    # the object's triangles: its BVH leaves' ranges
    node = packed.node
    stack, idx = [n0], []
    while stack:
        i = stack.pop()
        if node[i, 6] >= 0:
            stack += [int(node[i, 6]), int(node[i, 7])]
        else:
            s = -int(node[i, 6]) - 1
            idx.extend(range(s, s + int(node[i, 7])))
    tri = packed.tri[np.asarray(idx)]
    d = np.einsum("ntk,tk->nt", tri[None, :, 0:3] - np.asarray(pts, float)[:, None, :], tri[:, 9:12])
    return d.min(axis=1)
