"""Which mixed scenes ``MixedBlocks`` (blocks.py) takes: the conditions its compiled loop assumes."""

from __future__ import annotations

import numpy as np


def refusal(integrator) -> str | None:
    """Why the steps of ``integrator`` cannot run in the compiled loop (kernel.py), in a few words, or None:
    it needs a mixed scene (``MixedMoreauJean``) with a modal body, in 2D, on one process, every contact row
    made compliant by the modal body's static part (on the tangent rows too), fixed obstacles, the laws'
    work in the contact loss and nothing they store, the loads' time functions taken on many times at once,
    a diagonal mass and damping of the modes."""
    from .mixed import MixedMoreauJean

    if not isinstance(integrator, MixedMoreauJean) or integrator.modal is None:
        return "not a scene of rigid bodies beside a modal body"
    it, e = integrator, integrator.elastic
    ops, static = it.ops, e.ops.static
    checks = (
        (it.rigid.bodies.dim == 2, "a 3D scene (the loop is 2D)"),
        (it.alg.comm.size == 1, "a run on several MPI processes"),
        (bool(ops.p), "no contact rows"),
        (static is not None and it.modal.fields.static is not None, "no static part"),
        (bool(np.all(e.position_rows)) and not np.count_nonzero(e.carnot_rows),
         "a contact row off the modal body (rigid on both sides)"),
        (not ops.pt or (e._soft_t is not None and bool(np.all(e._soft_t))), "a tangent row off the modal body"),
        (not ops.moving, "moving obstacles"),
        (not e._elastic_stops and set(ops.laws.columns) <= {"contact_loss"}, "a contact law that stores energy or "
                                                                             "books it in a column of its own"),
        (hasattr(ops.load, "_varying") and hasattr(e.ops.load, "evaluate_block")
         and all(hasattr(f, "at_times") for f, _ in ops.load._varying), "loads not evaluated on many times at once"),
        (isinstance(e.ops.M, np.ndarray) and e.ops.M.ndim == 1
         and (e.ops.C is None or (isinstance(e.ops.C, np.ndarray) and e.ops.C.ndim == 1)),
         "the modes' mass or damping not diagonal"),
    )
    return next((why for fits, why in checks if not fits), None)
