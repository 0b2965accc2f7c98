"""The one place a case becomes objects: mesh -> finite-element model -> contact constraints -> the
system the time loop integrates (the full model, or the reduced one of ``method: modal``) and its
integrator. The pipeline, the studies, periodic/, the tests and the benchmarks all build through it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from mpi4py import MPI

from .fem.specs import ModelSpec, ReductionSpec

if TYPE_CHECKING:   # (type hints only: the modules below load dolfinx and PETSc)
    from .config.case import Case
    from .fem.fields import StateFields
    from .fem.model import Model
    from .fem.probes import Probes
    from .fem.reduced import ReducedModel
    from .mechanics.system import Operators
    from .nonsmooth.relation import Constraints


def model_spec(case: Case) -> ModelSpec:
    """What builds the finite-element model (fem_impact.fem.model.build_model)."""
    groups = [(("contacts", i, "nodes"), group) for i, contact in enumerate(case.contacts) for group in contact.nodes]
    return ModelSpec(case.material, dict(case.materials or {}), case.damping, case.initial, list(case.supports),
                     list(case.loads), case.solver.mass, case.mesh.hypothesis, case.mesh.axis or "y", groups)


def reduction_spec(case: Case) -> ReductionSpec:
    """The reduced model's choices of a ``method: modal`` case (fem_impact.fem.reduced)."""
    solver = case.solver
    return ReductionSpec(solver.modes, solver.tolerance, solver.static_correction, solver.dt, solver.t_end,
                         case.output.every,
                         case.damping.alpha, case.damping.beta)


def finite_element_model(case: Case, comm: MPI.Comm | None = None) -> Model:
    """The case's mesh and finite-element model (M, K, C, loads, supports; ``model.meshdata``)."""
    from .fem.mesh import build_mesh
    from .fem.model import build_model

    return build_model(model_spec(case), build_mesh(case.mesh, MPI.COMM_WORLD if comm is None else comm))


def model_and_constraints(case: Case, comm: MPI.Comm | None = None) -> tuple[Model, Constraints]:
    """The finite-element model and the case's contact constraints on it."""
    from .errors import ModelInputError
    from .nonsmooth.relation import build_constraints

    for i, contact in enumerate(case.contacts):
        if contact.type == "surface" and case.mesh.hypothesis == "axisymmetric":
            raise ModelInputError(("contacts", i, "type"), "a surface contact on an axisymmetric model is not built "
                                                           "yet (its mortar integrals would need the circle's weight "
                                                           "2 pi r): use a pair or an obstacle")
    model = finite_element_model(case, comm)
    return model, build_constraints(case.contacts, model)


@dataclass
class System:
    """What a case builds: the model and its constraints, the operators the time loop integrates, how
    to read physical fields from their state, the initial state and what the construction found."""

    model: Model
    constraints: Constraints
    probes: Probes | None        # the case's output.probes (None: not asked for)
    operators: Operators
    fields: StateFields
    U0: object                   # the initial state: PETSc vectors (full model) or modal coordinates
    V0: object
    summary: dict                # keys of the run's summary: the reduced model's modes, ...
    reduced: ReducedModel | None = None   # the reduced model (method: modal), else None
    rigid: object | None = None  # the rigid bodies (fem_impact.rigid.bodies.RigidBodies) of a scene with some, else None
    # a scene mixing rigid and elastic bodies: the elastic bodies' operators (the rigid bodies' dofs held,
    # P on the elastic dofs alone), else None
    elastic: Operators | None = None


def build_system(case: Case, comm: MPI.Comm | None = None, *, check_initial: bool = False,
                 probes: bool = False) -> System:
    """Build ``case`` on ``comm`` (default ``MPI.COMM_WORLD``): the reduced model for ``method: modal``,
    else the finite-element system itself. ``check_initial``: refuse an initial state that violates
    a contact (ModelInputError) before the operators are built; ``probes``: locate output.probes."""
    from .fem.probes import find_probes
    from .integrators import is_reduced
    from .nonsmooth.relation import check_initial_state

    model, cons = model_and_constraints(case, comm)
    if check_initial:
        check_initial_state(cons, model)
    found = find_probes(case.output.probes, model) if probes else None
    if any(model == "rigid" for model in case.bodies.values()):
        system = rigid_system(case, model, cons)
    elif any(model == "modal" for model in case.bodies.values()):
        from .errors import ModelInputError

        name = next(name for name, kind in case.bodies.items() if kind == "modal")
        raise ModelInputError(("bodies", name, "model"), "a modal body is taken beside rigid bodies only, for now "
                                                         "(the whole model reduced: solver.method: modal)")
    else:
        system = (reduced_system if is_reduced(case.solver) else full_system)(case, model, cons)
    system.probes = found
    return system


def rigid_system(case: Case, model: Model, cons: Constraints) -> System:
    """A scene with rigid bodies (fem_impact/rigid/): those of ``bodies`` with ``model: rigid`` in large
    rotations, the others elastic beside them (the mixed scene's step, rigid/mixed.py). What it does not
    take yet is refused, naming the key."""
    from .errors import ModelInputError
    from .rigid.bodies import rigid_bodies

    names = list(model.momentum_rows)
    unknown = sorted(set(case.bodies) - set(names))
    if unknown:
        raise ModelInputError(("bodies", unknown[0]), f"no body {unknown[0]} in the mesh (its bodies: "
                                                      f"{', '.join(names)})")
    rigid = [name for name in names if case.bodies.get(name, "elastic") == "rigid"]
    modal = [name for name in names if case.bodies.get(name) == "modal"]
    mixed = len(rigid) < len(names)
    refusals = [
        (case.supports and not mixed, ("supports",),
         "a rigid body takes no supports (hold it by contacts, or move an obstacle)"),
        (model.motion is not None, ("supports",), "a scene with rigid bodies takes fixed supports only, for now"),
        (case.solver.method != "moreau_jean", ("solver", "method"), "rigid bodies take moreau_jean (the default)"),
        (getattr(case.solver, "theta", 0.5) != 0.5, ("solver", "theta"), "rigid bodies take theta = 1/2"),
        ((case.damping.alpha or case.damping.beta) and not mixed, ("damping",),
         "a rigid body has no damping of its own"),
        (getattr(case.solver, "mass", None) == "redistributed", ("solver", "mass"),
         "a rigid body keeps its mass on every node (mass: consistent or lumped)"),
        (case.mesh.hypothesis == "axisymmetric", ("mesh", "hypothesis"),
         "a rigid body is not a solid of revolution here (plane_stress, plane_strain or 3D)"),
        (any(not (e.is_constant and e.at_time(0.0) == 0.0) for item in case.initial.displacement for e in item.value),
         ("initial", "displacement"), "a scene with rigid bodies starts where its mesh is (no initial displacement)"),
        (case.initial.source is not None, ("initial", "from"), "a scene with rigid bodies does not start from a "
                                                                "saved run yet"),
        (any(c.stiffness is not None or c.law not in ("newton",) for c in case.contacts), ("contacts",),
         "rigid bodies take Newton's law (restitution) and friction, for now"),
    ]
    if modal:
        plain = [name for name in names if name not in rigid and name not in modal]
        refusals += [
            (bool(plain), ("bodies", modal[0], "model"),
             f"a modal body beside a body modelled in full ({', '.join(plain)}) is not available yet: make "
             "those modal or rigid too"),
            (len(modal) > 1, ("bodies", modal[-1], "model"), "one modal body per scene, for now"),
        ]
    for refused, key, message in refusals:
        if refused:
            raise ModelInputError(key, message)
    system = full_system(case, model, cons)
    system.rigid = bodies = rigid_bodies(model, rigid, ("bodies",))
    _refuse_pairs_within_a_body(case, model, cons, bodies)
    if modal:
        system.elastic, system.reduced, summary = modal_part(case, model, cons, bodies, modal[0])
        system.summary.update(summary)
        system.summary["modal_body"] = modal[0]
    elif mixed:
        system.elastic = elastic_operators(model, cons, bodies)
    system.summary["rigid_bodies"] = {name: {"mass": float(m), "centre": [float(x) for x in c],
                                             "inertia": (float(j) if bodies.dim == 2 else j.tolist())}
                                      for name, m, c, j in zip(rigid, bodies.mass, bodies.centre, bodies.inertia)}
    return system


def _refuse_pairs_within_a_body(case: Case, model: Model, cons: Constraints, bodies) -> None:
    """A pair contact between two node groups of one rigid body constrains nothing that can change."""
    import numpy as np
    from mpi4py import MPI
    from scipy import sparse

    from .errors import ModelInputError

    P = sparse.coo_matrix(cons.P_local)
    owner = bodies.body[P.row]
    lo, hi = np.full(cons.p, len(bodies.names), dtype=np.int64), np.full(cons.p, -1, dtype=np.int64)
    np.minimum.at(lo, P.col, owner)
    np.maximum.at(hi, P.col, owner)
    model.comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
    model.comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
    for rows in cons.contacts:
        i = rows.index
        if case.contacts[i].type == "pair" and np.any((lo[rows.rows] == hi[rows.rows]) & (hi[rows.rows] >= 0)):
            body = bodies.names[int(hi[rows.rows].max())]
            raise ModelInputError(("contacts", i, "nodes"), f"both node groups of the pair are on the rigid body "
                                                            f"{body}: a pair within one rigid body never moves")


def _rigid_dofs_held(model: Model, bodies):
    """The rigid bodies' dofs (owned, local), M, K, C with them held as supports hold theirs (unit mass, no
    stiffness or damping there), and the diagonal that keeps the other dofs: the model of the elastic or modal
    bodies beside them."""
    import numpy as np
    from scipy import sparse

    from .errors import ModelInputError

    on = np.flatnonzero(bodies.body >= 0)
    if model.comm.allreduce(int(np.intersect1d(on, model.fixed).size)):
        raise ModelInputError(("supports",), "a support holds a rigid body's node (hold a rigid body by contacts, "
                                             "or move an obstacle)")
    rows = (on + model.first_node * model.bs).astype(np.int32)
    held = []
    for matrix, diagonal in ((model.M, 1.0), (model.K, 0.0), (model.C, 0.0)):
        if matrix is not None:
            matrix = matrix.copy()
            matrix.zeroRowsColumns(rows, diag=diagonal)
        held.append(matrix)
    keep = np.ones(model.U0.getLocalSize())
    keep[on] = 0.0
    return on, held, sparse.diags(keep)


def elastic_operators(model: Model, cons: Constraints, bodies) -> Operators:
    """The elastic bodies of a mixed scene: the model with the rigid bodies' dofs held (unit mass, no
    stiffness, no load there) and the contact rows on the elastic dofs alone."""
    from scipy import sparse

    from .mechanics.system import Operators

    on, held, keep = _rigid_dofs_held(model, bodies)
    tangents = keep @ sparse.csr_matrix(cons.tangent_local) if cons.pt else None
    return Operators(*held, HeldLoad(model.load, on), keep @ sparse.csr_matrix(cons.P_local), cons.d0,
                     cons.restitution, stop_compliance=cons.compliance,
                     friction=cons.friction if cons.pt else None, tangents=tangents, tangent_of=cons.tangent_of,
                     laws=cons.laws, relations=cons.relations)


def modal_part(case: Case, model: Model, cons: Constraints, bodies, name: str):
    """The modal body of a scene with rigid bodies: the model with the rigid bodies' dofs held as supports hold
    theirs, reduced (its lowest ``bodies.NAME.modes`` modes plus the static correction of the others at the
    contact rows, fem/reduced.py), and its modal equations as the elastic part's operators (rigid/mixed.py).
    Returns (those operators, the reduced model, the reduction's summary)."""
    import dataclasses

    import numpy as np
    from scipy import sparse

    from .errors import ModelInputError
    from .fem.model import LoadVector
    from .fem.reduced import prepare_reduced

    on, held, keep = _rigid_dofs_held(model, bodies)

    def without_rigid(vector):
        out = vector.copy()
        out.array[on] = 0.0
        return out

    load = LoadVector(without_rigid(model.load.constant), [(f, without_rigid(b)) for f, b in model.load.varying])
    elastic_model = dataclasses.replace(
        model, M=held[0], K=held[1], C=held[2], fixed=np.union1d(model.fixed, on).astype(np.int64), load=load,
        U0=without_rigid(model.U0), V0=without_rigid(model.V0),
        momentum_rows={body: rows_of for body, rows_of in model.momentum_rows.items() if body == name})
    on_body = lambda rows: sparse.csr_matrix(keep @ sparse.csr_matrix(rows))   # noqa: E731 (the rows on its dofs)
    elastic_cons = dataclasses.replace(cons, P_local=on_body(cons.P_local),
                                       tangent_local=on_body(cons.tangent_local) if cons.pt else cons.tangent_local)
    solver = case.solver
    spec = ReductionSpec(case.body_modes[name], 0.01, True, solver.dt, solver.t_end, case.output.every,
                         case.damping.alpha, case.damping.beta)
    try:
        red, summary = prepare_reduced(spec, elastic_model, elastic_cons)
    except ModelInputError as err:   # (its keys are solver.modes': this body's)
        raise ModelInputError(("bodies", name, "modes") if err.key and err.key[-1] == "modes" else err.key,
                              str(err.message)) from None
    return reduced_operators(red, elastic_cons), red, summary


class HeldLoad:
    """A load R(t) without its entries on held dofs (the rigid bodies' in a mixed scene's elastic part:
    the rigid bodies take theirs as a resultant and a moment)."""

    def __init__(self, load, held):
        self.load, self.held = load, held

    @property
    def time_dependent(self) -> bool:
        return self.load.time_dependent

    def evaluate(self, t: float, out):
        self.load.evaluate(t, out)
        out[self.held] = 0.0
        return out


def full_system(case: Case, model: Model, cons: Constraints) -> System:
    """The finite-element system itself (the full methods: moreau_jean, newmark, central_difference)."""
    import numpy as np
    from mpi4py import MPI

    from .fem.fields import StateFields
    from .mechanics.system import Operators

    ops = Operators(model.M, model.K, model.C, model.load, cons.P_local, cons.d0, cons.restitution,
                    massless=model.massless, stop_compliance=cons.compliance,
                    friction=cons.friction if cons.pt else None, tangents=cons.tangent_local,
                    tangent_of=cons.tangent_of, laws=cons.laws, relations=cons.relations)
    searched = [r for r in cons.relations.relations if getattr(r, "reach_dofs", None) is not None]
    if searched:
        # A surface contact's rows, found again as its bodies slide, may touch any of its nodes. They are
        # found again (app/sliding.py) by a scheme that takes new rows, without rigid bodies, and where no
        # support moves a node the search reads (its motion is not in the full model's displacement).
        from .integrators import integrator_class, scheme_of

        reach = np.unique(np.concatenate([r.reach_dofs for r in searched]))
        read = np.concatenate([r.read_dofs for r in searched])   # (every axis of the nodes a search reads)
        searches = getattr(integrator_class(scheme_of(case.solver)), "takes_new_rows", False)
        moved = model.motion is not None and bool(np.isin(read, model.motion.moving_dofs()).any())
        if searches and not any(m == "rigid" for m in case.bodies.values()) and \
                not model.comm.allreduce(moved, op=MPI.LOR):
            ops.reach = reach
    return System(model, cons, None, ops, StateFields(cons), model.U0, model.V0, {"modes": None})


def reduced_system(case: Case, model: Model, cons: Constraints) -> System:
    """Kept modes plus the static correction of the truncated ones (method ``modal``)."""
    from .fem.reduced import prepare_reduced

    red, summary = prepare_reduced(reduction_spec(case), model, cons)
    return System(model, cons, None, reduced_operators(red, cons), red.fields, red.Z0, red.Zdot0, summary, red)


def reduced_operators(red: ReducedModel, cons: Constraints) -> Operators:
    """The reduced model's modal equations as the integrators' operators, small and replicated: M = I,
    diagonal K and C, the contact rows on the modes (the rows' gaps, restitution, stops and friction)."""
    import numpy as np

    from .mechanics.system import Operators

    friction = {}
    if cons.pt:
        friction = dict(friction=cons.friction, tangents=red.tangents, tangent_of=cons.tangent_of)
    return Operators(np.ones(red.modes), red.stiffness, red.damping, red.load, red.rows, cons.d0, cons.restitution,
                     static=red.static, stop_compliance=cons.compliance, laws=cons.laws, relations=cons.relations,
                     **friction)


def make_integrator(case: Case, operators: Operators, rigid=None, elastic: Operators | None = None,
                    reduced=None):
    """The time integrator of ``solver.method`` (the reduced model: of its ``solver.scheme``; ``rigid``, a
    system's rigid bodies: Moreau-Jean on them, with ``elastic``, the elastic bodies beside them, if any:
    the modal equations of ``reduced``, a modal body's reduced model, where it is given)."""
    from .integrators import integrator_class, scheme_of

    if rigid is not None and elastic is not None:
        from .rigid.mixed import MixedMoreauJean

        return MixedMoreauJean(operators, elastic, rigid, case.solver.dt, modal=reduced)
    if rigid is not None:
        from .rigid.scheme import RigidMoreauJean

        return RigidMoreauJean(operators, rigid, case.solver.dt)
    return integrator_class(scheme_of(case.solver)).from_solver(operators, case.solver)
