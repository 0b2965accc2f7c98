"""Rigid bodies from a mesh: each body's mass, centre and inertia from its mass matrix, and the map from
its rigid motion to the nodes' displacements and velocities, exact for any rotation (docs/theory.md
s. 12).

A body's nodes sit at ``c + X_k`` at t = 0 (``X_k`` from its centre of mass ``c``). Moved rigidly to
the centre ``x`` and the rotation ``R``, node k is at ``x + R X_k``: its displacement is
``u_k = x - c + (R - I) X_k`` and its velocity ``v_k = v + omega x (R X_k)``. The mass, centre and
second moments come from the model's mass matrix ``M`` (``int rho phi_i phi_j``): ``m = 1^T M 1``,
``m c = X^T M 1``, ``S = X^T M X`` per body, exact for linear elements (``sum phi_n x_n = x``), so
that the kinetic energy ``1/2 V^T M V`` of the nodal velocities is ``1/2 m v^2 + 1/2 omega . J omega``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ..errors import ModelInputError
from ..fem.model import Model


@dataclass
class RigidBodies:
    """The rigid bodies of a model: per body its mass ``mass`` (nb), centre ``centre`` (nb x dim) and
    inertia about it at t = 0 (``inertia``: nb, about the normal in 2D; nb x 3 x 3 in 3D); per owned dof
    its body (``body``, -1: none), component (``component``) and the node's offset from the centre
    (``offset``, n_local x dim)."""

    names: list[str]
    dim: int
    mass: np.ndarray
    centre: np.ndarray
    inertia: np.ndarray
    body: np.ndarray
    component: np.ndarray
    offset: np.ndarray

    @property
    def rotations(self) -> int:
        """Rotational coordinates per body: 1 in 2D (the angle), 3 in 3D."""
        return 1 if self.dim == 2 else 3

    @property
    def size(self) -> int:
        """Generalized velocities per body: translation and rotation."""
        return self.dim + self.rotations


def rigid_bodies(model: Model, names: list[str], key: tuple) -> RigidBodies:
    """The bodies ``names`` of ``model`` as rigid bodies (every body of the model: a scene of rigid bodies)."""
    dim, bs, comm = model.meshdata.dim, model.bs, model.comm
    if dim == 1:
        raise ModelInputError(key, "a rigid body needs a 2D or 3D mesh (a 1D body has no rotation: reduce it to "
                                   "its rigid mode, solver.method: modal, as cases/bouncing_ball.yaml)")
    n_local = model.U0.getLocalSize()
    coords = model.node_coords[:model.n_owned_nodes, :dim]
    node_of = np.arange(n_local) // bs
    component = np.arange(n_local) % bs
    body = np.full(n_local, -1)
    for b, name in enumerate(names):
        rows = model.momentum_rows[name]
        mine = rows[:, 0] > 0.0
        if np.any(body[mine] >= 0):
            raise ModelInputError(key + (name,), f"body {name} shares nodes with body {names[body[mine].max()]}: "
                                                 "rigid bodies must be meshed apart")
        # (a node's dofs: every component belongs to the body whose mass is on its x component)
        nodes = np.unique(node_of[mine])
        body[np.isin(node_of, nodes)] = b
    mass, centre, inertia = [], [], []
    x_vec = model.M.createVecRight()
    y_vec = model.M.createVecRight()
    for b, name in enumerate(names):
        first = (body == b) & (component == 0)
        # Y_a: the node's coordinate a on its x dof (0 elsewhere): X^T M X on the x block of M
        columns = []
        for a in range(dim):
            y = np.zeros(n_local)
            y[first] = coords[node_of[first], a]
            columns.append(y)
        ones = first.astype(float)
        products = []
        for y in [ones, *columns]:
            x_vec.array[:] = y
            model.M.mult(x_vec, y_vec)
            products.append(y_vec.array.copy())
        local = np.array([[u @ w for w in products] for u in [ones, *columns]])
        sums = comm.allreduce(local)
        m = sums[0, 0]
        if not m > 0.0:
            raise ModelInputError(key + (name,), f"body {name} has no mass")
        c = sums[0, 1:] / m
        S = sums[1:, 1:] - m * np.outer(c, c)   # second moments about the centre
        mass.append(m)
        centre.append(c)
        inertia.append(np.trace(S) if dim == 2 else np.trace(S) * np.eye(3) - S)
    x_vec.destroy()
    y_vec.destroy()
    centre = np.array(centre)
    offset = np.zeros((n_local, dim))
    on = body >= 0
    offset[on] = coords[node_of[on]] - centre[body[on]]
    return RigidBodies(list(names), dim, np.array(mass), centre, np.array(inertia), body, component, offset)


def rotation_2d(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def cayley(w: np.ndarray) -> np.ndarray:
    """``(I - W/2)^-1 (I + W/2)`` for the skew matrix W of ``w``: a rotation (orthogonal to round-off)
    by the angle 2 atan(|w| / 2) about w, the implicit midpoint rule's step of R' = R W."""
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    return np.linalg.solve(np.eye(3) - 0.5 * W, np.eye(3) + 0.5 * W)


class NodalMap:
    """The nodes' displacements and velocities (owned dofs) from the bodies' rigid motion, and the
    nodal fields of unit generalized velocities (the columns of ``B``: ``V = B nu``)."""

    def __init__(self, bodies: RigidBodies):
        self.bodies = bodies
        self.on = np.flatnonzero(bodies.body >= 0)
        self.b = bodies.body[self.on]
        self.c = bodies.component[self.on]
        self.X = bodies.offset[self.on]

    def _arms(self, rotations: np.ndarray) -> np.ndarray:
        """``R_b X_k`` per dof on a body (its node's arm from the centre, now)."""
        return np.einsum("kij,kj->ki", rotations[self.b], self.X)

    def displacement(self, centres: np.ndarray, rotations: np.ndarray, out: np.ndarray) -> None:
        bodies = self.bodies
        arms = self._arms(rotations)
        u = centres[self.b] - bodies.centre[self.b] + arms - self.X
        out[:] = 0.0
        out[self.on] = u[np.arange(self.on.size), self.c]

    def velocity(self, velocities: np.ndarray, spins: np.ndarray, rotations: np.ndarray, out: np.ndarray) -> None:
        """``v + omega x (R X)`` (2D: omega a scalar about the normal)."""
        arms = self._arms(rotations)
        v = velocities[self.b].copy()
        if self.bodies.dim == 2:
            w = spins[self.b, 0]
            v[:, 0] -= w * arms[:, 1]
            v[:, 1] += w * arms[:, 0]
        else:
            v += np.cross(spins[self.b], arms)
        out[:] = 0.0
        out[self.on] = v[np.arange(self.on.size), self.c]

    def columns(self, rotations: np.ndarray) -> sparse.csr_matrix:
        """``B`` (n_local x nb * size, sparse: a dof moves with its body's translation along its own axis
        and with its spins): the nodal velocity of each unit generalized velocity, the rotations now."""
        bodies = self.bodies
        dim, size, nb = bodies.dim, bodies.size, len(bodies.names)
        arms = self._arms(rotations)
        rows, at = self.on, np.arange(self.on.size)
        if dim == 2:   # e_z x (R X): (-a_y, a_x)
            spin = np.column_stack([-arms[:, 1], arms[:, 0]])[at, self.c][:, None]
        else:          # e_r x (R X), r = x, y, z
            spin = np.stack([np.cross(axis, arms)[at, self.c] for axis in np.eye(3)], axis=1)
        cols = np.column_stack([self.b * size + self.c, self.b[:, None] * size + dim + np.arange(spin.shape[1])])
        data = np.column_stack([np.ones(rows.size), spin])
        return sparse.csr_matrix((data.ravel(), (np.repeat(rows, cols.shape[1]), cols.ravel())),
                                 shape=(self.bodies.body.size, nb * size))
