"""Small helpers for the parametric Gmsh scripts in meshes/ (named groups, the file format read here)."""

from __future__ import annotations

from pathlib import Path

import gmsh


def add_named_groups(dim: int, groups: dict[str, list[int]]) -> None:
    """One physical group per name over entities of dimension ``dim`` (top dimension: bodies;
    lower: node groups, as fem-impact reads them)."""
    for name, tags in groups.items():
        gmsh.model.setPhysicalName(dim, gmsh.model.addPhysicalGroup(dim, list(tags)), name)


def write_msh(path) -> Path:
    """Write the current model as MSH 4.1 text (what ``fem_impact.fem.mesh`` reads)."""
    path = Path(path)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    gmsh.write(str(path))
    return path
