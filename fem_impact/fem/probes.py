"""Probes: named points of the structure, each read at the mesh node nearest to it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

from ..errors import ModelInputError
from ..parallel import allsum
from . import dolfinx_api as dx
from .model import AXES, Model, pad_vector

if TYPE_CHECKING:   # (type hints only)
    from ..integrators.state import StepState


@dataclass
class Probes:
    """Named points, each read at the mesh node nearest to it (one owner rank per probe)."""

    names: list[str]
    owned_dofs: np.ndarray     # (n_probes x dim) local dof of each component, -1 off-owner
    distance: np.ndarray       # distance from the asked point to the node used
    dim: int

    def values(self, state: StepState, comm: MPI.Comm, fields) -> np.ndarray:
        """(u, v) at every probe as one flat array [p0.ux, p0.uy, ..., p0.vx, ...]."""
        if getattr(fields, "replicated", False) and comm.size > 1:   # the reduced model: on every rank, no sum
            u, v = fields.point_reader(self.owned_dofs, comm)(state)
            return np.stack([u, v], axis=1).reshape(-1)
        out = np.zeros((len(self.names), 2, self.dim))
        mine = self.owned_dofs[:, 0] >= 0
        if mine.any():
            out[mine, 0], out[mine, 1] = fields.at(state, self.owned_dofs[mine])
        return allsum(comm, out).reshape(-1)

    def values_block(self, block, comm: MPI.Comm, fields) -> np.ndarray:
        """``values`` at every step of a block of steps (L x columns), one reduction."""
        out = np.zeros((len(block), len(self.names), 2, self.dim))
        mine = self.owned_dofs[:, 0] >= 0
        if mine.any():
            out[:, mine, 0], out[:, mine, 1] = fields.at_block(block, self.owned_dofs[mine])
        return allsum(comm, out).reshape(len(block), -1)

    def columns(self) -> list[str]:
        return [f"{name}.{q}{AXES[c]}" for name in self.names for q in "uv" for c in range(self.dim)]


def find_probes(points: dict, model: Model) -> Probes:
    """The probes ``points`` (name -> point, the case's ``output.probes``), each at its nearest node."""
    dim, bs, comm = model.meshdata.dim, model.bs, model.comm
    coords = model.node_coords[: model.n_owned_nodes, :dim]
    names, dofs, distances = [], [], []
    for name, point in points.items():
        key = ("output", "probes", name)
        point = np.asarray(pad_vector(point, dim, key, "probe"), dtype=float)
        if coords.size:
            d = np.linalg.norm(coords - point, axis=1)
            k = int(np.argmin(d))
            mine = (float(d[k]), model.first_node + k)
        else:
            mine = (np.inf, -1)
        best = min(comm.allgather(mine))  # nearest node; ties go to the lowest global index
        _check_inside(model, key, point)
        local = best[1] - model.first_node
        owned = 0 <= local < model.n_owned_nodes and best[1] >= 0
        names.append(name)
        dofs.append([local * bs + c if owned else -1 for c in range(dim)])
        distances.append(best[0])
    return Probes(names, np.array(dofs, dtype=np.int64).reshape(-1, dim), np.array(distances), dim)


def _check_inside(model: Model, key, point) -> None:
    """A probe farther from the mesh than 1e-6 of its size is a mistake (a unit, a sign), not the nearest node."""
    coords = model.node_coords[:, : model.meshdata.dim]
    dim = model.meshdata.dim
    lo = np.min(model.comm.allgather(coords.min(axis=0) if coords.size else np.full(dim, np.inf)), axis=0)
    hi = np.max(model.comm.allgather(coords.max(axis=0) if coords.size else np.full(dim, -np.inf)), axis=0)
    tol = 1e-6 * float(np.max(hi - lo))
    lo, hi = (np.where(np.abs(b) < tol, 0.0, b) for b in (lo, hi))   # (round-off of the mesh generator)
    full = np.zeros(3)
    full[: len(point)] = point
    distance = model.comm.allreduce(dx.distance_to_mesh(model.meshdata.mesh, full, tol), op=MPI.MIN)
    if distance > tol:
        box = ", ".join(f"[{a:g}, {b:g}]" for a, b in zip(lo, hi, strict=True))
        raise ModelInputError(key, f"the point {[float(v) for v in point]} is outside the mesh (which spans "
                                   f"{box}); a probe must lie on the structure")
