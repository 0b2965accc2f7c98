"""A contact as the nonsmooth layer takes it, as plain data (validated by fem_impact/config/case.py)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class Contact:
    name: str
    type: str
    nodes: list[str]
    normal: list[float] | None   # obstacle, pair: unit; surface: None (the surface's own)
    gap: float | None = None
    restitution: float = 0.0
    coupling: str = "each"      # "each": a row per node (pair); "mean": one row on the group's mean
    stiffness: float | None = None   # N/m per row: an elastic stop (None: rigid)
    law: str = "newton"         # the contact law (fem_impact.nonsmooth.laws): newton, elastic_stop, or registered
    law_keys: dict = field(default_factory=dict)   # the law's own keys, as its schema validated them
    friction: float = 0.0       # Coulomb's coefficient mu on every row of the contact (0: frictionless)
    point: list[float] | None = None   # obstacle: a point of its plane; each node's gap its own distance to it
    # obstacle: the plane's displacement from where gap or point put it, one expression in t per axis
    # (fem_impact.expressions.Expression; None: the plane is fixed)
    motion: list | None = None
    surface: str | None = None   # surface: the boundary group (edges in 2D, faces in 3D) the nodes meet

    @property
    def law_is_inferred(self) -> bool:
        """Whether the law follows from the keys (newton, or elastic_stop when a stiffness is given)."""
        return self.law == ("elastic_stop" if self.stiffness is not None else "newton")
