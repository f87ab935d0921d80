"""Mesh files of 3-D scenes (OBJ, STL), read and checked with trimesh for ``renderer.scene3.pack_scene``.

A module of its own so that trimesh (and the scipy it loads, ~0.4 s CPU) is imported only for a scene that
has a mesh file: planes, spheres and boxes are packed without it. Each refusal is a ``ValueError`` naming
the scene file and the object (``where``).
"""

from __future__ import annotations

import os

import numpy as np
import trimesh

from .scene import Mesh

#: a triangle smaller than this is degenerate (m^2: a 10 um x 10 um right triangle's is 5e-11)
DEGENERATE_AREA_M2 = 1e-12


def load_mesh(obj: Mesh, where: str) -> trimesh.Trimesh:
    """Read and check a mesh object (scaled and moved as the scene says); ``where`` names it in errors."""
    if not os.path.isfile(obj.path):
        raise ValueError(f"{where}: mesh file not found: {obj.path}")
    try:
        m = trimesh.load(obj.path, force="mesh", process=True)
    except Exception as exc:  # trimesh raises many kinds for a bad file: one message naming it
        raise ValueError(f"{where}: cannot read mesh {obj.path}: {exc}") from None
    if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
        raise ValueError(f"{where}: mesh {obj.path} is empty (no triangles)")
    m.apply_scale(obj.scale)
    m.apply_translation(obj.offset_m)
    check_mesh(m, where)
    return m


def check_mesh(m: trimesh.Trimesh, where: str) -> None:
    """Refuse an empty, non-manifold or inconsistently wound mesh, or one with a degenerate triangle."""
    if len(m.faces) == 0:
        raise ValueError(f"{where}: mesh is empty (no triangles)")
    area = m.area_faces
    bad = np.flatnonzero(~(area > DEGENERATE_AREA_M2))
    if bad.size:
        raise ValueError(f"{where}: degenerate triangle {int(bad[0])} (area {float(area[bad[0]]):.3g} m^2; "
                         f"{bad.size} such): remove it or repair the mesh")
    if not m.is_watertight:
        raise ValueError(f"{where}: mesh is not closed (non-manifold: an edge not shared by exactly two "
                         "triangles): the proxy needs a closed surface")
    if not m.is_winding_consistent:
        raise ValueError(f"{where}: mesh triangles are not consistently wound (non-manifold orientation)")
    if m.volume < 0:
        m.invert()   # inward normals: turn them out


def mesh_arrays(obj: Mesh, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A mesh object's triangles as ``renderer.scene3.box_arrays`` gives a box's: corners (T, 3, 3, m),
    unit face normals (T, 3) and each triangle's corners' vertex normals (T, 3, 3)."""
    m = load_mesh(obj, where)
    tri = np.asarray(m.triangles, float)
    return tri, np.asarray(m.face_normals, float), np.asarray(m.vertex_normals, float)[np.asarray(m.faces)]
