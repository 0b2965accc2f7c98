"""A rigid body's event-driven flights (``study response --flight events``; docs/studies.md): the body in
translation as the shooting's linear system (shooting.py's ``ReducedSystem``).

A rigid body struck only through its centre (every impact on a row whose line of action passes through
the centre: a disk or a ball on a plane, under its lowest node), loaded without torque (gravity, a body
acceleration) and started without spin never turns: its motion is a translation ``x(t)``, linear, with
``m x'' = F(t)`` between impacts and Newton's law at a row ``j``: ``x'+ = x'- - (1 + e) (n_j . x'- -
d_j') n_j / (m |n_j|^2) m``. In the coordinates ``Z = sqrt(m) x`` (unit mass, as the modes'), ``P = H_t /
sqrt(m)`` (``H_t`` the rows' translation columns, ``P B`` of the rigid body's nodal map) and the load
``B_t^T R(t) / sqrt(m)``: shooting's system with ``w^2 = 0``.

What this does not describe is refused with a :class:`ShootingError` naming why: several bodies, an
elastic body beside it, friction, a load with a torque about the centre, an initial spin; and, during a
flight, an impact on a row off the centre's line (``ReducedSystem.spins``), which would turn the body
(then ``--flight scheme`` integrates its rotation).
"""

from __future__ import annotations

import numpy as np

from ..fem.reduced import ModalLoad
from ..rigid.bodies import NodalMap

ARM = 1e-9   # of the body's size: a row's (or a load's) moment arm about the centre below this is none


def rigid_system(built, system_class, error):
    """(system, start, probe_rows) of a scene of one rigid body in translation (the module's docstring):
    the system a ``system_class`` (shooting's ReducedSystem); ``error`` the exception class to refuse with
    (shooting's ShootingError)."""
    bodies, ops = built.rigid, built.operators
    if built.elastic is not None or len(bodies.names) != 1:
        raise error("the event-driven flight takes one rigid body alone (a scene of several bodies, or of rigid "
                    "and elastic ones: --flight scheme)")
    if ops.pt:
        raise error("the event-driven flight takes frictionless contacts only")
    dim = bodies.dim
    B = NodalMap(bodies).columns(np.tile(np.eye(dim), (1, 1, 1))).toarray()   # (n x (dim + rotations))
    m = float(bodies.mass[0])
    root = np.sqrt(m)
    extent = max(float(np.abs(bodies.offset).max(initial=0.0)), 1e-300)
    H = np.asarray(ops.P_local.T @ B)   # (P_local: the rows as columns, n x p, sparse: H is p x (dim + rotations))
    arms = np.abs(H[:, dim:]).max(axis=1, initial=0.0)
    spins = arms > ARM * extent * np.maximum(np.abs(H[:, :dim]).max(axis=1, initial=0.0), 1e-300)

    load = ops.load
    parts = [load.constant.array_r] + [b.array_r for _, b in load.varying]
    for part in parts:   # (a torque about the centre would turn the body)
        generalized = B.T @ part
        if np.abs(generalized[dim:]).max(initial=0.0) > ARM * extent * max(np.abs(generalized[:dim]).max(), 1e-300):
            raise error("a load turns the rigid body (a torque about its centre): the event-driven flight takes "
                        "it in translation (a body acceleration, or forces through its centre); --flight scheme "
                        "integrates its rotation")
    translation = B[:, :dim]
    # (the load on the translation, B_t^T R(t) / sqrt(m): as the modes' Y1^T R(t))
    modal = ModalLoad(translation.T @ parts[0] / root, [(f, translation.T @ b.array_r / root) for f, b in load.varying])

    V0 = np.asarray(built.V0, dtype=float)
    nu0 = np.linalg.lstsq(B, V0, rcond=None)[0]
    if np.abs(V0 - B @ nu0).max(initial=0.0) > 1e-12 * max(np.abs(V0).max(initial=0.0), 1e-300) or \
            np.abs(nu0[dim:]).max(initial=0.0) * extent > 1e-12 * max(np.abs(nu0[:dim]).max(initial=0.0), 1e-300):
        raise error("the rigid body starts with a spin: the event-driven flight takes it in translation "
                    "(--flight scheme integrates its rotation)")
    system = system_class(np.zeros(dim), np.zeros(dim), modal, H[:, :dim] / root, np.asarray(ops.d0, float),
                           np.asarray(ops.restitution, float), ops.relations if ops.moving else None, spins=spins)
    start = np.concatenate([np.zeros(dim), root * nu0[:dim]])
    probes = built.probes
    rows = np.array([[translation[d] / root for d in dofs] for dofs in probes.owned_dofs]).reshape(-1, dim)
    return system, start, rows
