"""The finite-element model: M, K, C as PETSc matrices, supports, loads R(t) and initial state."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from . import dolfinx_api as dx
from .specs import BodyValue, Material, ModelSpec
from ..errors import ModelInputError, SimulationError
from ..expressions import Expression, parse_expression
from .mesh import MeshData
from .prescribed import PrescribedMotion, build_motion, effective_loads

log = logging.getLogger(__name__)

AXES = "xyz"


@dataclass
class NodeSet:
    """The nodes of a named group, in one global order (sorted by coordinates) on every rank.

    ``coords`` (n x 3) and ``global_node`` (n,) describe all nodes of the group; ``local_node``
    (n,) is this rank's owned node index of each, or -1 where another rank owns it.
    """

    name: str
    coords: np.ndarray
    global_node: np.ndarray
    local_node: np.ndarray

    def __len__(self) -> int:
        return len(self.global_node)


class LoadVector:
    """R(t) = R_const + sum_i f_i(t) b_i, with the vectors b_i assembled once.

    ``evaluate`` fills the owned entries of R(t) into a numpy array (the integrators' vectors).
    """

    def __init__(self, constant: PETSc.Vec, varying: list[tuple[Expression, PETSc.Vec]]):
        self.constant = constant
        self.varying = varying
        self._constant = constant.array_r.copy()
        self._varying = [(f, b.array_r.copy()) for f, b in varying]

    @property
    def time_dependent(self) -> bool:
        return bool(self.varying)

    def evaluate(self, t: float, out: np.ndarray) -> np.ndarray:
        out[:] = self._constant
        for f, b in self._varying:
            out += load_factor(f, t) * b
        return out


def load_factor(f: Expression, t: float) -> float:
    """The value of a load's time function at t; a run whose load overflows stops with its name."""
    value = f.at_time(t)
    if not math.isfinite(value):
        what = getattr(f, "what", None) or f"the load '{f.source}'"   # (a support's motion names itself)
        raise SimulationError(f"{what} is no longer finite at t = {t:.6g} ({value})")
    return value


@dataclass
class Model:
    """Everything the integrators need from the finite-element side."""

    meshdata: MeshData
    V: object
    bs: int
    M: PETSc.Mat
    K: PETSc.Mat
    C: PETSc.Mat | None
    fixed: np.ndarray          # local owned dof indices held at zero by supports
    load: LoadVector
    U0: PETSc.Vec
    V0: PETSc.Vec
    node_coords: np.ndarray    # local node coordinates (owned, then ghosts) x 3
    n_owned_nodes: int
    first_node: int
    # Per body, m_b (owned entries, n_local x dim): column c holds int_body rho phi_j e_c, so that
    # m_b[:, c] . V is the body's momentum along c and its column sum the body's mass.
    momentum_rows: dict[str, np.ndarray] = field(default_factory=dict)
    massless: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # owned dofs without mass
    motion: PrescribedMotion | None = None   # supports that move (fem/prescribed.py)

    @property
    def comm(self) -> MPI.Comm:
        return self.meshdata.comm

    @property
    def dofs(self) -> int:
        return self.K.getSize()[0]

    def held_rows(self) -> np.ndarray:
        """Global PETSc row indices of the dofs held by supports (owned by this rank)."""
        return (self.fixed + self.first_node * self.bs).astype(np.int32)

    def dof_keys(self) -> np.ndarray:
        """Owned dofs' numbers independent of the partition: node key x block size + component."""
        nodes = dx.node_keys(self.V)[: self.n_owned_nodes]
        return (nodes[:, None] * self.bs + np.arange(self.bs)[None, :]).reshape(-1)

    def regular_stiffness(self) -> PETSc.Mat:
        """K with a unit diagonal on held dofs: regular for a constrained body (static solves)."""
        K = self.K.copy()
        K.zeroRowsColumns(self.held_rows(), diag=1.0)
        return K

    def node_set(self, name: str, key: tuple) -> NodeSet:
        return node_set(self.meshdata, self.V, name, key)


def node_set(meshdata: MeshData, V, name: str, key: tuple) -> NodeSet:
    """Gather a node group into its global, coordinate-sorted order."""
    if name not in meshdata.node_groups:
        known = ", ".join(sorted(meshdata.node_groups)) or "none"
        raise ModelInputError(key, f"no node group '{name}' in the mesh (node groups: {known})")
    n_owned, first = dx.owned_nodes(V)
    nodes = dx.vertex_dofs(V, meshdata.node_groups[name])
    nodes = nodes[nodes < n_owned]
    coords = dx.node_coordinates(V)[nodes]
    parts = meshdata.comm.allgather((coords, nodes + first))
    all_coords = np.concatenate([c for c, _ in parts]).reshape(-1, 3)
    all_global = np.concatenate([g for _, g in parts]).astype(np.int64)
    if all_global.size == 0:
        raise ModelInputError(key, f"node group '{name}' has no nodes")
    order = np.lexsort(np.round(all_coords, 12).T[::-1])
    all_coords, all_global = all_coords[order], all_global[order]
    local = np.where((all_global >= first) & (all_global < first + n_owned), all_global - first, -1)
    return NodeSet(name, all_coords, all_global, local)


def pad_vector(values, dim: int, key: tuple, what: str) -> list:
    """A vector given with 1 component means its x component in any dimension."""
    values = list(values)
    if len(values) == dim:
        return values
    if len(values) == 1:
        zero = parse_expression(0.0) if isinstance(values[0], Expression) else 0.0
        return values + [zero] * (dim - 1)
    wanted = "1 component" if dim == 1 else f"1 or {dim} components"
    raise ModelInputError(key, f"{what} has {len(values)} components; the mesh is {dim}D (give {wanted})")


def build_model(spec: ModelSpec, meshdata: MeshData) -> Model:
    msh, dim = meshdata.mesh, meshdata.dim
    V = dx.vector_space(msh)
    bs = V.dofmap.index_map_bs
    n_owned, first = dx.owned_nodes(V)
    coords = dx.node_coordinates(V)
    materials = _materials(spec, meshdata)

    u, w = ufl.TrialFunction(V), ufl.TestFunction(V)
    dxm = dx.body_measure(msh, meshdata.cell_tags)
    hypothesis = _hypothesis(spec, dim)
    mass_form = stiff_form = None
    for body, tag in meshdata.bodies.items():
        mat = materials[body]
        measure = dxm if meshdata.cell_tags is None else dxm(tag)
        section = _section(mat, dim, hypothesis, msh)
        m_b = mat.rho * section * ufl.inner(u, w) * measure
        k_b = _strain_work(u, w, mat, dim, hypothesis, msh) * measure
        mass_form = m_b if mass_form is None else mass_form + m_b
        stiff_form = k_b if stiff_form is None else stiff_form + k_b
    M = dx.assemble_matrix(mass_form)
    K = dx.assemble_matrix(stiff_form)
    if spec.mass == "lumped":
        M = _lumped(M)

    fixed = _fixed_dofs(spec, meshdata, V, bs)
    axis = None
    if hypothesis[0] == "axisymmetric":
        axis = _axis_dofs(meshdata, coords[:n_owned], bs, hypothesis[1])
        fixed = np.union1d(fixed, axis)
    massless = np.zeros(0, dtype=np.int64)
    if spec.mass == "redistributed":
        massless = np.setdiff1d(_contact_dofs(spec, meshdata, V, bs), fixed)
        M = _redistributed(M, massless, first * bs, spec)
    motion = build_motion(spec, meshdata, lambda name, key: node_set(meshdata, V, name, key), bs, M, K,
                          spec.damping, first * bs, ("supports",), axis)
    rows = (fixed + first * bs).astype(np.int32)
    # Supports: zero rows and columns; unit mass and zero stiffness on the diagonal keep S
    # regular for any Newmark parameters while the held dofs see a zero right-hand side.
    M.zeroRowsColumns(rows, diag=1.0)
    K.zeroRowsColumns(rows, diag=0.0)
    C = None
    if spec.damping.alpha or spec.damping.beta:
        C = K.copy()
        C.scale(spec.damping.beta)
        C.axpy(spec.damping.alpha, M, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)

    load = _loads(spec, meshdata, V, bs, materials, dim, dxm, fixed, hypothesis, motion)
    U0, V0 = M.createVecs()
    _initial_field(spec, "displacement", meshdata, V, bs, coords[:n_owned], U0)
    _initial_field(spec, "velocity", meshdata, V, bs, coords[:n_owned], V0)
    for vec in (U0, V0):
        vec.array[fixed] = 0.0
    momentum = _momentum_rows(meshdata, V, materials, dim, dxm, hypothesis)
    log.info("model: %d dofs, %s mass", K.getSize()[0], spec.mass)
    if spec.mass == "redistributed":
        momentum = _redistributed_momentum_rows(momentum, M, fixed)
    return Model(meshdata, V, bs, M, K, C, fixed, load, U0, V0, coords, n_owned, first, momentum, massless, motion)


def _momentum_rows(meshdata: MeshData, V, materials, dim: int, dxm, hypothesis) -> dict[str, np.ndarray]:
    """Per body the rows m_b = 1_b^T M of its material alone, assembled once (``int rho phi_j``).

    Assembled over the body's cells, so that a node shared with another body counts its share of
    each; the supports do not enter (a held dof has V = 0), and a lumped mass has the same row sums.
    """
    w = ufl.TestFunction(V)
    rows = {}
    for body, tag in meshdata.bodies.items():
        mat = materials[body]
        measure = dxm if meshdata.cell_tags is None else dxm(tag)
        # rho and a constant section scale the assembled vector, so that the form (and its compiled
        # kernel, cached on disk) does not depend on the material; 2 pi r stays in the form.
        axisymmetric = hypothesis[0] == "axisymmetric"
        scale = mat.rho * (1.0 if axisymmetric or dim == 3 else mat.area)
        weight = _section(mat, dim, hypothesis, meshdata.mesh) if axisymmetric else 1.0
        columns = []
        for comp in range(dim):
            unit = ufl.as_vector([1.0 if j == comp else 0.0 for j in range(dim)])
            columns.append(scale * dx.assemble_vector(weight * ufl.inner(unit, w) * measure).array_r)
        rows[body] = np.column_stack(columns)
    return rows


def _redistributed_momentum_rows(rows: dict[str, np.ndarray], M: PETSc.Mat,
                                 fixed: np.ndarray) -> dict[str, np.ndarray]:
    """The momentum rows of the redistributed mass: ``1_b^T M`` with ``1_b`` the body's dofs (those
    with a share in the assembled rows), so that massless contact nodes carry no momentum and
    their neighbours carry the mass they took over. (A node two bodies share counts in both.)"""
    indicator, row = M.createVecs()
    out = {}
    for body, m_b in rows.items():
        columns = []
        for comp in range(m_b.shape[1]):
            indicator.array[:] = m_b[:, comp] > 0.0
            M.mult(indicator, row)
            column = row.array_r.copy()
            column[fixed] = 0.0   # held dofs have a unit placeholder mass and V = 0
            columns.append(column)
        out[body] = np.column_stack(columns)
    return out


def _materials(spec: ModelSpec, meshdata: MeshData) -> dict[str, Material]:
    if spec.material is not None:
        return {body: spec.material for body in meshdata.bodies}
    missing = sorted(set(meshdata.bodies) - set(spec.materials))
    unknown = sorted(set(spec.materials) - set(meshdata.bodies))
    known = ", ".join(sorted(meshdata.bodies))
    if unknown:
        raise ModelInputError(("materials", unknown[0]), f"no body '{unknown[0]}' in the mesh (bodies: {known})")
    if missing:
        raise ModelInputError(("materials",), f"no material for body '{missing[0]}' (bodies: {known})")
    return dict(spec.materials)


def _hypothesis(spec: ModelSpec, dim: int) -> tuple[str, int]:
    """(the 2D hypothesis, the index of the radial coordinate: 0 about the y axis, 1 about x)."""
    if spec.hypothesis != "plane_stress" and dim != 2:
        raise ModelInputError(("mesh", "hypothesis"), f"applies to 2D models only (this mesh is {dim}D): remove it")
    return spec.hypothesis, 0 if spec.axis == "y" else 1


def _section(mat: Material, dim: int, hypothesis: tuple[str, int], msh):
    """What a 2D integral is multiplied by: the thickness (area), or the circle 2 pi r (axisymmetric)."""
    if dim == 3:
        return 1.0
    if hypothesis[0] == "axisymmetric":
        return 2.0 * np.pi * ufl.SpatialCoordinate(msh)[hypothesis[1]]
    return mat.area


def _strain_work(u, w, mat: Material, dim: int, hypothesis: tuple[str, int], msh):
    """The stiffness form's integrand ``sigma(u) : eps(w)`` times the section (docs/theory.md s. 2).

    2D: plane stress (sigma_zz = 0: lambda = E nu / (1 - nu^2)), plane strain (eps_zz = 0: the 3D
    lambda) or axisymmetric: on the meridian plane, with the hoop strain ``u_r / r`` and its stress.
    """
    eps, eps_w = ufl.sym(ufl.grad(u)), ufl.sym(ufl.grad(w))
    if dim == 1:
        return mat.area * mat.E * ufl.inner(eps, eps_w)
    mu = mat.E / (2.0 * (1.0 + mat.nu))
    lmbda = mat.E * mat.nu / ((1.0 + mat.nu) * (1.0 - 2.0 * mat.nu))   # 3D, plane strain, axisymmetric
    if dim == 2 and hypothesis[0] == "plane_stress":
        lmbda = mat.E * mat.nu / (1.0 - mat.nu**2)
    if dim == 2 and hypothesis[0] == "axisymmetric":
        radial = hypothesis[1]
        r = ufl.SpatialCoordinate(msh)[radial]
        hoop, hoop_w = u[radial] / r, w[radial] / r
        trace = ufl.tr(eps) + hoop
        sigma = 2.0 * mu * eps + lmbda * trace * ufl.Identity(2)
        sigma_hoop = 2.0 * mu * hoop + lmbda * trace
        return 2.0 * np.pi * r * (ufl.inner(sigma, eps_w) + sigma_hoop * hoop_w)
    sigma = 2.0 * mu * eps + lmbda * ufl.tr(eps) * ufl.Identity(dim)
    return (mat.area if dim == 2 else 1.0) * ufl.inner(sigma, eps_w)


def _axis_dofs(meshdata: MeshData, coords: np.ndarray, bs: int, radial: int) -> np.ndarray:
    """The radial dofs of the owned nodes on the symmetry axis (a ring of radius 0 cannot open);
    a node at a negative radius is bad input."""
    r = coords[:, radial]
    tolerance = 1e-9 * meshdata.extent
    lowest = meshdata.comm.allreduce(float(r.min(initial=np.inf)), op=MPI.MIN)
    if lowest < -tolerance:
        name = "xy"[radial]
        raise ModelInputError(("mesh", "axis"), f"an axisymmetric mesh lies in the half plane {name} >= 0 (the "
                                                f"radius), but it has a node at {name} = {lowest:.6g}")
    return np.flatnonzero(np.abs(r) <= tolerance) * bs + radial


def _lumped(M: PETSc.Mat) -> PETSc.Mat:
    """Row-sum lumped mass as a diagonal PETSc matrix."""
    diag, ones = M.createVecs()
    ones.set(1.0)
    M.mult(ones, diag)
    L = PETSc.Mat().createAIJ(M.getSizes(), nnz=1, comm=M.getComm())
    L.setDiagonal(diag)
    L.assemble()
    return L


def _contact_dofs(spec: ModelSpec, meshdata: MeshData, V, bs: int) -> np.ndarray:
    """Owned dofs (all components) of the nodes that any contact acts on."""
    dofs = []
    for key, group in spec.contact_groups:
        nodes = node_set(meshdata, V, group, key)
        owned = nodes.local_node[nodes.local_node >= 0]
        dofs.append((owned[:, None] * bs + np.arange(meshdata.dim)).ravel())
    return np.unique(np.concatenate(dofs)).astype(np.int64) if dofs else np.zeros(0, dtype=np.int64)


def _redistributed(M: PETSc.Mat, massless: np.ndarray, first_dof: int, spec: ModelSpec) -> PETSc.Mat:
    """Mass redistribution (Khenous, Laborde & Renard 2008): no mass on the contact dofs.

    The rows and columns of the contact dofs are removed from the consistent M, and the mass
    they held goes to the diagonal of their neighbours (dofs coupled to them in M): neighbour j
    gets back its coupling ``M_jc`` plus the share ``M_jc / s_c`` of the contact dof's row mass
    ``r_c`` (``s_c`` = its coupling to the dofs that keep their mass). One product ``M w`` with
    ``w_c = 1 + r_c / s_c`` on the contact dofs gives all of it. Total mass is conserved exactly;
    the centre of mass moves by O(h) toward the interior (KLR also keep it, with a wider stencil).
    """
    comm = M.getComm().tompi4py()
    if not comm.allreduce(massless.size, op=MPI.SUM):
        return M
    ones, row_mass = M.createVecs()
    ones.set(1.0)
    M.mult(ones, row_mass)
    contact = ones.duplicate()
    contact.set(0.0)
    contact.array[massless] = 1.0
    keep = ones.duplicate()
    keep.array[:] = 1.0 - contact.array_r
    coupling = row_mass.duplicate()
    M.mult(keep, coupling)                       # s_c: row mass toward the dofs that keep theirs
    s = coupling.array_r[massless]
    if np.any(s <= 0.0):
        raise ModelInputError(("solver", "mass"), "mass redistribution needs every contact node to share an "
                                                  "element with a node that is not in contact (refine the mesh "
                                                  "near the contacts)")
    weights = contact.duplicate()
    weights.set(0.0)
    weights.array[massless] = 1.0 + row_mass.array_r[massless] / s
    gained = row_mass.duplicate()
    M.mult(weights, gained)
    gained.array[massless] = 0.0
    R = M.copy()
    R.zeroRowsColumns((massless + first_dof).astype(np.int32), diag=0.0)
    diagonal = R.getDiagonal()
    diagonal.axpy(1.0, gained)
    R.setDiagonal(diagonal)
    return R


def _fixed_dofs(spec: ModelSpec, meshdata: MeshData, V, bs: int) -> np.ndarray:
    fixed = []
    for i, support in enumerate(spec.supports):
        nodes = node_set(meshdata, V, support.nodes, ("supports", i, "nodes"))
        owned = nodes.local_node[nodes.local_node >= 0]
        for comp in support.fix:
            if comp >= meshdata.dim:
                if support.all_components:   # fix: all -> the components this dimension has
                    continue
                raise ModelInputError(("supports", i, "fix"),
                                      f"component {AXES[comp]} does not exist in {meshdata.dim}D")
            fixed.append(owned * bs + comp)
    return np.unique(np.concatenate(fixed)).astype(np.int64) if fixed else np.zeros(0, dtype=np.int64)


def _loads(spec, meshdata, V, bs, materials, dim, dxm, fixed, hypothesis, motion=None) -> LoadVector:
    constant = dx.function(V, "R").vector.copy()
    constant.set(0.0)
    varying = []
    held = [np.zeros(motion.count)] if motion else None   # the loads the moving supports take

    def add(expr: Expression, vec: PETSc.Vec, key: tuple) -> None:
        if motion:
            on_held = motion.patterns.T @ vec.array_r
            if expr.is_constant:
                held[0] += float(expr.evaluate()) * on_held
            else:
                held.append(on_held)
        vec.array[fixed] = 0.0
        if expr.is_constant:
            value = float(expr.evaluate())
            if not np.isfinite(value):
                raise ModelInputError(key, f"'{expr.source}' is not a finite number")
            constant.axpy(value, vec)
        else:
            varying.append((expr, vec))

    w = ufl.TestFunction(V)
    for i, load in enumerate(spec.loads):
        if load.traction is not None:
            key = ("loads", i, "traction")
            if load.nodes not in meshdata.node_groups:
                node_set(meshdata, V, load.nodes, ("loads", i, "nodes"))   # (its error: no such group)
            ds, tags = dx.boundary_facet_measure(meshdata.mesh, meshdata.node_groups[load.nodes],
                                                 meshdata.cell_tags, meshdata.bodies)
            area = meshdata.comm.allreduce(sum(dx.assemble_scalar(1.0 * _section(materials[body], dim, hypothesis,
                                                                                 meshdata.mesh) * ds(tag))
                                               for body, tag in tags.items()))
            if not area > 0.0:
                raise ModelInputError(("loads", i, "nodes"), f"node group '{load.nodes}' holds no boundary "
                                                             f"{'edge' if dim == 2 else 'face' if dim == 3 else 'end'} "
                                                             "of the mesh: a traction acts on one")
            for comp, expr in enumerate(pad_vector(load.traction, dim, key, "traction")):
                if _is_zero(expr):
                    continue
                unit = ufl.as_vector([1.0 if j == comp else 0.0 for j in range(dim)])
                form = sum(_section(materials[body], dim, hypothesis, meshdata.mesh) * ufl.inner(unit, w) * ds(tag)
                           for body, tag in tags.items())
                add(expr, dx.assemble_vector(form), key)
        elif load.nodes is not None:
            key = ("loads", i, "force")
            nodes = node_set(meshdata, V, load.nodes, ("loads", i, "nodes"))
            owned = nodes.local_node[nodes.local_node >= 0]
            # A total force is shared equally by the nodes of the group.
            for comp, expr in enumerate(pad_vector(load.force, dim, key, "force")):
                if _is_zero(expr):
                    continue
                vec = constant.duplicate()
                vec.set(0.0)
                vec.array[owned * bs + comp] = 1.0 / len(nodes)
                add(expr, vec, key)
        else:
            key = ("loads", i, "acceleration")
            bodies = meshdata.bodies if load.body == "all" else None
            if bodies is None:
                if load.body not in meshdata.bodies:
                    known = ", ".join(sorted(meshdata.bodies))
                    raise ModelInputError(("loads", i, "body"), f"no body '{load.body}' in the mesh (bodies: {known})")
                bodies = {load.body: meshdata.bodies[load.body]}
            for comp, expr in enumerate(pad_vector(load.acceleration, dim, key, "acceleration")):
                if _is_zero(expr):
                    continue
                unit = ufl.as_vector([1.0 if j == comp else 0.0 for j in range(dim)])
                form = None
                for body, tag in bodies.items():
                    mat = materials[body]
                    measure = dxm if meshdata.cell_tags is None else dxm(tag)
                    section = _section(mat, dim, hypothesis, meshdata.mesh)
                    term = mat.rho * section * ufl.inner(unit, w) * measure
                    form = term if form is None else form + term
                add(expr, dx.assemble_vector(form), key)
    if motion:
        motion.held_load = meshdata.comm.allreduce(np.array(held), op=MPI.SUM)
        motion.load_functions = [f for f, _ in varying]
        varying = varying + effective_loads(motion, constant, fixed)
    return LoadVector(constant, varying)


def _is_zero(expr: Expression) -> bool:
    return expr.is_constant and float(expr.evaluate()) == 0.0


def _initial_field(spec, which, meshdata, V, bs, coords, out: PETSc.Vec) -> None:
    out.set(0.0)
    entries: list[BodyValue] = getattr(spec.initial, which)
    values = out.array.reshape(-1, bs)
    n_owned = values.shape[0]
    for i, entry in enumerate(entries):
        key = ("initial", which, i) if entry.body is not None else ("initial", which)
        if entry.body is None:
            nodes = np.arange(n_owned)
        else:
            if entry.body not in meshdata.bodies:
                known = ", ".join(sorted(meshdata.bodies))
                raise ModelInputError(key, f"no body '{entry.body}' in the mesh (bodies: {known})")
            nodes = _body_nodes(meshdata, V, entry.body, n_owned)
        comps = pad_vector(entry.value, meshdata.dim, key, which)
        x = coords[nodes]
        for comp, expr in enumerate(comps):
            values[nodes, comp] = expr.evaluate(x=x[:, 0], y=x[:, 1], z=x[:, 2], shape=len(nodes))
            if not meshdata.comm.allreduce(bool(np.isfinite(values[nodes, comp]).all()), op=MPI.LAND):
                where = key + (comp,) if entry.body is None else key + ("value", comp)
                raise ModelInputError(where, f"{expr.source!r} is not finite at some nodes (inf or nan)")


def _body_nodes(meshdata: MeshData, V, body: str, n_owned: int) -> np.ndarray:
    cell_nodes = dx.cell_nodes(V)
    if meshdata.cell_tags is not None:
        tags = meshdata.cell_tags
        cells = tags.indices[tags.values == meshdata.bodies[body]]
        cell_nodes = cell_nodes[cells]
    nodes = np.unique(cell_nodes)
    return nodes[nodes < n_owned]
