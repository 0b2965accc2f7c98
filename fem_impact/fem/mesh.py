"""Meshes: built-in shapes and Gmsh files, with named bodies (cell groups) and node groups."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

from . import dolfinx_api as dx
from .specs import MeshSpec
from ..errors import ModelInputError

log = logging.getLogger(__name__)


@dataclass
class MeshData:
    """A distributed mesh with the names a case file refers to.

    ``bodies`` maps a body name to its cell tag (``cell_tags`` is None for a single body
    covering the whole mesh); ``node_groups`` maps a group name to the local vertex indices
    of its nodes on this rank (owned and ghost).
    """

    mesh: dx.Mesh
    dim: int
    cell_tags: object | None
    bodies: dict[str, int]
    node_groups: dict[str, np.ndarray]
    description: str

    @property
    def comm(self) -> MPI.Comm:
        return self.mesh.comm


def bar_dimensions(spec: MeshSpec) -> tuple[float, float]:
    """Cross-section (height, width) of the built-in bar (``MeshSpec.bar_dimensions``)."""
    return spec.bar_dimensions()


def build_mesh(spec: MeshSpec, comm: MPI.Comm = MPI.COMM_WORLD) -> MeshData:
    if spec.file is not None:
        return _read_gmsh(spec, comm)
    return _builtin_bar(spec, comm)


def _builtin_bar(spec: MeshSpec, comm: MPI.Comm) -> MeshData:
    dim = spec.bar_dim
    length, cells = spec.length, spec.cells
    height, width = spec.bar_dimensions()
    # Cells across follow the aspect ratio so that elements stay close to square.
    across = lambda size: max(1, int(round(cells * size / length)))  # noqa: E731
    if dim == 1:
        msh = dx.interval(comm, cells, length)
    elif dim == 2:
        msh = dx.rectangle(comm, cells, across(height), length, height, hex=spec.elements == "hex")
    else:
        msh = dx.box(comm, (cells, across(height), across(width)), (length, height, width), hex=spec.elements == "hex")
    tol = 1e-9 * length
    planes = {"left": (0, 0.0), "right": (0, length)}
    if dim >= 2:
        planes.update(bottom=(1, 0.0), top=(1, height))
    if dim == 3:
        planes.update(back=(2, 0.0), front=(2, width))
    groups = {
        name: dx.locate_vertices(msh, lambda x, a=axis, c=coord: np.abs(x[a] - c) < tol)
        for name, (axis, coord) in planes.items()
    }
    if dim >= 2:  # the edges (2D: corners) where an end meets a side, e.g. a stop under the tip
        for end in ("left", "right"):
            for side in ("bottom", "top"):
                groups[f"{end}_{side}"] = np.intersect1d(groups[end], groups[side])
    return MeshData(msh, dim, None, {"bar": 0}, groups, f"built-in bar, {dim}D, {cells} cells along")


def _read_gmsh(spec: MeshSpec, comm: MPI.Comm) -> MeshData:
    import gmsh

    path = spec.file
    info = None
    if comm.rank == 0:
        gmsh.initialize()
        gmsh.option.setNumber("General.Terminal", 0)
        try:
            gmsh.merge(str(path))
            info = _gmsh_groups(gmsh.model)
        except Exception as exc:  # gmsh raises plain Exceptions with its own message
            info = {"error": str(exc)}
    info = comm.bcast(info, root=0)
    if "error" in info:
        if comm.rank == 0:
            gmsh.finalize()
        raise ModelInputError(("mesh", "file"), f"cannot read Gmsh file {path}: {info['error']}")
    dim = info["dim"]
    if dim < 1:
        if comm.rank == 0:
            gmsh.finalize()
        raise ModelInputError(("mesh", "file"), f"{path.name} has only point (0-dimensional) physical groups: name "
                                                "the bodies (physical groups of the mesh's dimension) and node groups")
    if spec.dim is not None and spec.dim != dim:
        if comm.rank == 0:
            gmsh.finalize()
        raise ModelInputError(("mesh", "dim"), f"is {spec.dim} but {path.name} holds a {dim}D mesh")
    if not info["bodies"]:
        if comm.rank == 0:
            gmsh.finalize()
        raise ModelInputError(("mesh", "file"), f"{path.name} has no physical group of dimension {dim} (bodies)")
    msh, cell_tags = dx.gmsh_model_to_mesh(gmsh.model if comm.rank == 0 else None, comm, dim)
    if comm.rank == 0:
        gmsh.finalize()
    coords = msh.geometry.x
    extent = float(np.ptp(coords[:, :dim], axis=0).max()) if coords.size else 1.0
    extent = comm.allreduce(extent, op=MPI.MAX)
    tol = 1e-8 * extent
    groups = {}
    for name, points in info["node_groups"].items():
        tree = cKDTree(points)
        groups[name] = dx.locate_vertices(msh, lambda x, t=tree: t.query(x.T, distance_upper_bound=tol)[0] < tol)
    return MeshData(msh, dim, cell_tags, info["bodies"], groups, f"Gmsh file {path.name}, {dim}D")


def _gmsh_groups(model) -> dict:
    """Bodies (top-dimension physical groups) and node coordinates of the lower-dimension ones."""
    groups = model.getPhysicalGroups()
    if not groups:
        return {"error": "no physical groups (name the bodies and node groups in the .geo/.py script)"}
    dim = max(d for d, _ in groups)
    bodies, node_groups = {}, {}
    for d, tag in groups:
        name = model.getPhysicalName(d, tag) or f"group_{d}_{tag}"
        if d == dim:
            bodies[name] = tag
        else:
            _, xyz = model.mesh.getNodesForPhysicalGroup(d, tag)
            node_groups[name] = np.asarray(xyz, dtype=float).reshape(-1, 3)
    return {"dim": dim, "bodies": bodies, "node_groups": node_groups}
