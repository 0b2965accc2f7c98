"""The watch on surface contacts' sliding: their rows are found on the geometry at t = 0 (small
sliding, docs/theory.md s. 2.7); a run whose rows slide farther than a share of a cell stops,
naming the contact, the node and how far it slid, instead of going on with partners it no longer
faces."""

from __future__ import annotations

import numpy as np

from ..errors import SimulationError
from ..parallel import allsum


class SlidingWatch:
    """An observer of the time loop (``write``, ``write_block``) over the surface contacts of ``cons``."""

    def __init__(self, cons, fields, comm):
        self.fields, self.comm = fields, comm
        self.parts = []
        for c in cons.contacts:
            relation = cons.relations.relations[cons.contacts.index(c)]
            T = getattr(relation, "sliding", None)
            if T is None:
                continue
            dofs = np.unique(T.nonzero()[0])
            self.parts.append((c.name, relation, dofs, T[dofs]))

    def __bool__(self) -> bool:
        return bool(self.parts)

    def write(self, state) -> None:
        for name, relation, dofs, T in self.parts:
            u, _ = self.fields.at(state, dofs)
            slid = allsum(self.comm, np.asarray(T.T @ u).ravel())
            over = np.abs(slid) / relation.sliding_limit
            worst = int(np.argmax(over)) if over.size else 0
            if over.size and over[worst] > 1.0:
                found = relation.found
                row = worst % found.r
                where = ", ".join(f"{v:.6g}" for v in found.x[row])
                share = relation.sliding_limit[worst] / found.size[row]
                raise SimulationError(
                    f"contact {name}: the node at ({where}) slid {abs(slid[worst]):.3g} m along the surface by "
                    f"t = {state.t:.6g} s, more than {share:g} of its cell ({found.size[row]:.3g} m): a surface "
                    "contact's rows are found on the geometry at t = 0 (small sliding); surfaces that slide "
                    "farther are not built yet (docs/limitations.md)")

    def write_block(self, block) -> None:
        """A block's last step (between contacts the rows slide little: checked where the block ends)."""
        self.write(block.state(len(block) - 1))
