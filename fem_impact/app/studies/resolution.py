"""Resolution of a case: wave speed, mesh size and Courant number ``c dt / h``.

``c = sqrt(E / rho)``, the bar wave speed, the largest over the materials (the fastest waves
set the explicit stability limit); ``h`` is ``length / cells`` for the built-in bar (in 2D and
3D the cells across follow the aspect ratio, so ``h`` is the element size there too) and the
smallest element edge of a mesh file.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np


def wave_speed(case) -> float:
    """Largest bar wave speed sqrt(E/rho) over the case's materials, in the case's units."""
    materials = [case.material] if case.material is not None else list(case.materials.values())
    return max(math.sqrt(m.E / m.rho) for m in materials)


def mesh_size(case) -> float:
    """``length / cells`` of the built-in bar, or the smallest element edge of a mesh file."""
    if case.mesh.file is None:
        return case.mesh.length / case.mesh.cells
    path = Path(case.mesh.file)
    return _smallest_edge(str(path), path.stat().st_mtime_ns)


@functools.lru_cache(maxsize=16)
def _smallest_edge(path: str, mtime: int) -> float:
    """The shortest distance between two corner nodes of one element of the top dimension."""
    import gmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(path)
        dim = gmsh.model.getDimension()
        tags, coords, _ = gmsh.model.mesh.getNodes()
        xyz = np.zeros((int(tags.max()) + 1, 3))
        xyz[tags.astype(int)] = coords.reshape(-1, 3)
        smallest = math.inf
        types, _, node_tags = gmsh.model.mesh.getElements(dim)
        for etype, nodes in zip(types, node_tags, strict=True):
            props = gmsh.model.mesh.getElementProperties(etype)
            per, corners = props[3], props[5]
            conn = nodes.astype(int).reshape(-1, per)[:, :corners]
            for i in range(corners):
                for j in range(i + 1, corners):
                    d = np.linalg.norm(xyz[conn[:, i]] - xyz[conn[:, j]], axis=1)
                    smallest = min(smallest, float(d.min()))
    finally:
        gmsh.finalize()
    return smallest


def courant(case) -> float:
    """The case's Courant number ``c dt / h``."""
    return wave_speed(case) * case.solver.dt / mesh_size(case)


def dt_for(case, courant_number: float) -> float:
    """The time step of Courant number ``courant_number`` on the case's mesh."""
    return courant_number * mesh_size(case) / wave_speed(case)
