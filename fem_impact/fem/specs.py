"""What the finite-element model is built from, as plain data: the mesh, materials, damping, initial
state, supports and loads (the case file validates them: fem_impact/config/schema.py), and the
reduced model's choices. Nothing here reads a file or knows the case format."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..expressions import Expression


@dataclass
class MeshSpec:
    shape: str | None = None
    file: Path | None = None
    dim: int | None = None
    length: float = 1.0
    cells: int = 100
    height: float | None = None
    width: float | None = None
    elements: str = "simplex"
    hypothesis: str = "plane_stress"   # 2D: plane_stress | plane_strain | axisymmetric
    axis: str | None = None            # axisymmetric: the symmetry axis, "y" (radius x) or "x" (radius y)

    # The built-in bar's documented defaults, defined here only: the mesh, the size estimate
    # (limits) and the exact solutions (references) read them from the case.
    @property
    def bar_dim(self) -> int:
        """The built-in bar's dimension: ``dim``, by default 1 (a rod)."""
        return self.dim or 1

    def bar_dimensions(self) -> tuple[float, float]:
        """Cross-section (height, width) of the built-in bar: by default height length/20, width = height."""
        height = self.height if self.height is not None else self.length / 20.0
        return height, self.width if self.width is not None else height


@dataclass
class Material:
    E: float
    rho: float
    nu: float = 0.0
    area: float = 1.0


@dataclass
class Damping:
    alpha: float = 0.0
    beta: float = 0.0


@dataclass
class BodyValue:
    body: str | None
    value: list[Expression]


@dataclass
class Initial:
    displacement: list[BodyValue] = field(default_factory=list)
    velocity: list[BodyValue] = field(default_factory=list)
    source: Path | None = None   # initial.from: a saved run's last state (its checkpoint), instead of the fields


@dataclass
class Support:
    nodes: str
    fix: list[int]
    all_components: bool = False   # fix: all (every component the mesh's dimension has)
    # Prescribed motion: one expression in t per component of ``fix`` (in its order: x, y, z);
    # None: held at zero (and no reaction column).
    displacement: list[Expression] | None = None


@dataclass
class Load:
    nodes: str | None = None
    body: str | None = None
    force: list[Expression] | None = None
    acceleration: list[Expression] | None = None
    traction: list[Expression] | None = None


@dataclass
class ModelSpec:
    """Everything :func:`fem_impact.fem.model.build_model` takes besides the mesh."""

    material: Material | None               # one material for every body, or
    materials: dict[str, Material]          # one per body (cell group)
    damping: Damping
    initial: Initial
    supports: list[Support]
    loads: list[Load]
    mass: str = "consistent"                # consistent | lumped | redistributed
    hypothesis: str = "plane_stress"        # 2D: plane_stress | plane_strain | axisymmetric (mesh.hypothesis)
    axis: str = "y"                         # axisymmetric: the symmetry axis (mesh.axis)
    # redistributed: the node groups the contacts act on, with their key path for errors
    contact_groups: list[tuple[tuple, str]] = field(default_factory=list)


@dataclass
class ReductionSpec:
    """The reduced model's choices (the case's ``solver`` section of ``method: modal``)."""

    modes: int | str                 # a count, or "auto"
    tolerance: float                 # modes: auto: the largest neglected flexibility per row
    static_correction: bool
    dt: float                        # s: the time step and the output interval set the scene's cut-off
    t_end: float                     # s: the run's length (the loads' band is sampled over it)
    output_every: int
    alpha: float = 0.0               # Rayleigh damping, C = alpha M + beta K
    beta: float = 0.0
