"""Meshes: built-in shapes and Gmsh files, with named bodies (cell groups) and node groups."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from mpi4py import MPI

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

    @property
    def extent(self) -> float:
        """The largest range of the node coordinates along an axis (the model's size), on every rank."""
        x = self.mesh.geometry.x[:, : self.dim]
        return self.comm.allreduce(float(np.ptp(x, axis=0).max()) if x.size else 0.0, op=MPI.MAX)


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
    from .gmsh_utils import MshError, read_msh

    path = spec.file
    data, info = None, None
    if comm.rank == 0:
        try:
            data = read_msh(path)
        except MshError as exc:
            data = {"error": str(exc)}
        # The small part to every rank; nodes and cells stay on rank 0, dolfinx distributes them.
        info = {k: v for k, v in data.items() if k not in ("x", "cells", "cell_body")}
        info["nodes_per_cell"] = data["cells"].shape[1] if "cells" in data else 0
    info = comm.bcast(info, root=0)
    if "error" in info:
        raise ModelInputError(("mesh", "file"), f"cannot read Gmsh file {path}: {info['error']}")
    dim = info["dim"]
    if dim < 1:
        raise ModelInputError(("mesh", "file"), f"{path.name} has only point (0-dimensional) physical groups: name "
                                                "the bodies (physical groups of the mesh's dimension) and node groups")
    if spec.dim is not None and spec.dim != dim:
        raise ModelInputError(("mesh", "dim"), f"is {spec.dim} but {path.name} holds a {dim}D mesh")
    if comm.rank == 0:
        x, cells, cell_body = data["x"], data["cells"], data["cell_body"]
    else:
        x, cells = np.zeros((0, 3)), np.zeros((0, info["nodes_per_cell"]), dtype=np.int64)
        cell_body = np.zeros(0, dtype=np.int32)
    try:
        msh, cell_tags = dx.gmsh_cells_to_mesh(comm, info["element_type"], cells, x, cell_body, dim)
    except ValueError as exc:
        raise ModelInputError(("mesh", "file"), f"cannot use Gmsh file {path}: {exc}") from None
    # A node group is the nodes of its own physical group's elements, by node identity: a node of
    # another body at the same place (two bodies meshed apart that touch) is not in it.
    groups = {name: dx.input_nodes_to_vertices(msh, nodes) for name, nodes in info["node_groups"].items()}
    return MeshData(msh, dim, cell_tags, info["bodies"], groups, f"Gmsh file {path.name}, {dim}D")
