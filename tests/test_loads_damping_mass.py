"""Loads, Rayleigh damping and the lumped mass on cases with exact answers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from conftest import CASES, run_case_file
from fem_impact.build import model_and_constraints
from fem_impact.config.case import load_case
from fem_impact.integrators import Newmark, Operators, integrate

BAR = CASES / "impacting_bar.yaml"
NO_CONTACT = ["contacts=[]", "output.vtk=false"]


class Momentum:
    """Total momentum 1^T M V and centroid displacement (1^T M U) / m per component."""

    def __init__(self, model):
        self.model = model
        self.ones = model.M.createVecs()[0]
        self.ones.set(1.0)
        self.Mones = model.M.createVecs()[0]
        model.M.mult(self.ones, self.Mones)
        self.rows = []

    def write(self, s):
        bs = self.model.bs
        mv = (self.Mones.array_r * s.V).reshape(-1, bs).sum(axis=0)
        mu = (self.Mones.array_r * s.U).reshape(-1, bs).sum(axis=0)
        self.rows.append([s.t, *mv, *mu])


def run_with_momentum(*overrides):
    case = load_case(BAR, list(overrides))
    model, cons = model_and_constraints(case, MPI.COMM_WORLD)
    ops = Operators(model.M, model.K, model.C, model.load, cons.P_local, cons.d0, cons.restitution)
    obs = Momentum(model)
    final = integrate(Newmark(ops, case.solver.dt), model.U0, model.V0, case.solver.t_end, [obs])
    mass = obs.Mones.array_r.reshape(-1, model.bs)[:, 0].sum()
    return np.array(obs.rows), mass, final


def test_time_dependent_force_on_a_node_group_gives_its_impulse():
    """Free rod, total force sin(2 pi t) on the right end: momentum (1 - cos 2 pi t) / 2 pi."""
    rows, mass, final = run_with_momentum("initial.velocity=[0.0]", "loads=[{nodes: right, force: ['sin(2*pi*t)']}]",
                                          "solver.t_end=1.5", "solver.dt=0.002", "mesh.cells=50", *NO_CONTACT)
    t, p = rows[:, 0], rows[:, 1]
    exact = (1 - np.cos(2 * np.pi * t)) / (2 * np.pi)
    assert mass == pytest.approx(1.0)
    assert np.abs(p - exact).max() < 1e-5          # trapezoidal rule on the load: O(dt^2)
    assert abs(final.energy.error) < 1e-10 * final.energy.external_work


def test_gravity_on_a_2d_strip_is_free_fall():
    """Body acceleration (0, -9.81) on a free strip: centroid at -g t^2/2, exact for Newmark."""
    rows, mass, final = run_with_momentum("mesh.dim=2", "mesh.cells=20", "initial.velocity=[0.0]",
                                          "loads=[{body: all, acceleration: [0, -9.81]}]", "solver.t_end=0.5",
                                          "solver.dt=0.01", *NO_CONTACT)
    t = rows[:, 0]
    height = 1.0 / 20
    m = height * 1.0 * 1.0  # area (thickness) 1, rho 1
    np.testing.assert_allclose(rows[:, 2], -9.81 * m * t, atol=1e-12)          # momentum y
    np.testing.assert_allclose(rows[:, 4] / m, -9.81 * t**2 / 2, atol=1e-12)   # centroid y
    np.testing.assert_allclose(rows[:, 1], 0.0, atol=1e-12)                     # nothing along x


def test_damped_clamped_rod_settles_at_the_static_tip_displacement(tmp_path):
    """Clamped at x = 0, step force F at x = L, Rayleigh damping: u(L) -> F L / (E A)."""
    summary, h = run_case_file(
        BAR, tmp_path, "initial.velocity=[0.0]", "supports=[{nodes: left, fix: [x]}]",
        "loads=[{nodes: right, force: [0.01]}]", "damping={alpha: 2.0, beta: 0.001}", "mesh.cells=40",
        "solver.dt=0.01", "solver.t_end=20.0", *NO_CONTACT,
    )
    assert h["right_ux"][-1] == pytest.approx(0.01, rel=1e-4)
    assert h["left_ux"].max() == 0.0 and h["left_vx"].max() == 0.0   # the support holds
    assert np.all(np.diff(h["damping_loss"]) >= -1e-15)              # damping only dissipates
    # Work done = strain energy stored + damping loss (no kinetic energy left).
    assert h["external_work"][-1] == pytest.approx(h["strain"][-1] + h["damping_loss"][-1], rel=1e-6)
    assert h["strain"][-1] == pytest.approx(0.5 * 0.01 * 0.01, rel=1e-3)
    assert summary["max_energy_error"] < 1e-9 * h["external_work"][-1]


def test_lumped_mass_impact_loss_is_one_over_two_n(tmp_path):
    """With a lumped mass and e = 0 one impact removes 1/(2 n_el) of the energy (docs/benchmarks.md B2)."""
    for n in (50, 100):
        _, h = run_case_file(BAR, Path(tmp_path) / str(n), "solver.mass=lumped", f"mesh.cells={n}",
                             f"solver.dt={0.5 / n}", "solver.t_end=2.5", "output.vtk=false")
        loss = (h["impact_loss"][-1] + h["contact_loss"][-1]) / 0.5
        assert loss == pytest.approx(1 / (2 * n), rel=0.02)


# --- tractions: a force per unit area, integrated over a node group's boundary faces --------------------

def _traction_model(dim: int, traction, cells: int = 4, elements: str = "hex"):
    import fem_impact as fi
    from fem_impact.build import finite_element_model

    mesh = {"shape": "bar", "dim": dim, "length": 1.0, "cells": cells, "elements": elements}
    if dim > 1:
        mesh["height"] = 0.5
    if dim == 3:
        mesh["width"] = 0.25
    material = {"E": 200.0, "rho": 1.0, "nu": 0.0 if dim == 1 else 0.3, **({"area": 0.1} if dim < 3 else {})}
    case = fi.Case.from_dict({"name": "traction", "mesh": mesh, "material": material,
                              "loads": [{"nodes": "right", "traction": traction}], "solver": {"dt": 0.01, "t_end": 0.01}})
    return finite_element_model(case, MPI.COMM_SELF)


@pytest.mark.parametrize("dim, area", [(1, 0.1), (2, 0.5 * 0.1), (3, 0.5 * 0.25)])
def test_a_traction_gives_the_force_of_its_area_shared_as_the_elements_share_it(dim, area):
    """2 Pa along x on the bar's right end: a total of 2 x its area (1D: the section; 2D: height x thickness),
    on the end's nodes alone; in 2D the end's two edges give their nodes 1/4, 1/2, 1/4 of it."""
    model = _traction_model(dim, [2.0] + [0.0] * (dim - 1))
    R = np.zeros(model.U0.getLocalSize())
    model.load.evaluate(0.0, R)
    fx = R.reshape(-1, dim)[:, 0]
    assert fx.sum() == pytest.approx(2.0 * area, rel=1e-12)
    assert np.abs(R.reshape(-1, dim)[:, 1:]).max(initial=0.0) == 0.0
    x = model.node_coords[:model.n_owned_nodes, 0]
    assert np.all(fx[~np.isclose(x, 1.0)] == 0.0)
    if dim == 2:
        y = model.node_coords[:model.n_owned_nodes, 1]
        end = np.isclose(x, 1.0)
        assert fx[end][np.argsort(y[end])] == pytest.approx(2.0 * area * np.array([0.25, 0.5, 0.25]), rel=1e-12)


@pytest.mark.parametrize("dim, elements", [(2, "hex"), (2, "simplex"), (3, "hex"), (3, "simplex")])
def test_a_uniform_traction_gives_the_uniform_stress_at_every_node(dim, elements):
    """The patch test of the load: a bar held by symmetry on its left end (x) and at one corner (the rest of
    the rigid motion), pulled by t on its right end, is in uniform stress sigma_xx = t: every node's static
    displacement is the linear field u_x = t x / E, u_y = -nu t y / E (3D and plane stress alike, u_z too)
    to round-off, on quadrilaterals and triangles, hexahedra and tetrahedra."""
    from petsc4py import PETSc

    t, E, nu = 3.0, 200.0, 0.3
    model = _traction_model(dim, [t, 0.0] + [0.0] * (dim - 2), cells=6, elements=elements)
    x = model.node_coords[:model.n_owned_nodes, :dim]
    held = [k * dim for k in np.flatnonzero(np.isclose(x[:, 0], 0.0))]   # x on the left end
    corner = np.flatnonzero(np.all(np.isclose(x, 0.0), axis=1))[0]
    held += [corner * dim + c for c in range(1, dim)]                     # the corner's other components
    if dim == 3:   # the left end's edge along z through the corner: y held (no spin about x)
        edge = np.flatnonzero(np.isclose(x[:, 0], 0.0) & np.isclose(x[:, 1], 0.0))
        held += [k * dim + 1 for k in edge]
    K = model.K.copy()
    K.zeroRowsColumns(np.array(held, dtype=np.int32), diag=1.0)
    R = model.M.createVecRight()
    model.load.evaluate(0.0, R.array)
    R.array[held] = 0.0
    U = R.duplicate()
    ksp = PETSc.KSP().create(MPI.COMM_SELF)
    ksp.setOperators(K)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.solve(R, U)
    exact = np.zeros_like(x)
    exact[:, 0] = t * x[:, 0] / E
    for c in range(1, dim):
        exact[:, c] = -nu * t * x[:, c] / E
    assert U.array.reshape(-1, dim) == pytest.approx(exact, abs=1e-12 * t / E)


def test_a_traction_and_a_force_on_one_load_are_refused(tmp_path):
    import fem_impact as fi
    from fem_impact.errors import CaseError

    with pytest.raises(CaseError, match=r"loads\[0\]\.traction.*not both"):
        fi.Case.from_dict({"name": "t", "mesh": {"shape": "bar"}, "material": {"E": 1.0, "rho": 1.0},
                           "loads": [{"nodes": "right", "force": [1.0], "traction": [1.0]}],
                           "solver": {"dt": 0.01, "t_end": 0.01}})


def test_a_traction_in_t_and_a_parameter_runs_and_is_written_resolved(tmp_path):
    """A traction ``p*t`` on the end of a free 2D bar: the parameter counts as used, case.resolved.yaml keeps
    the expression, and the bar's momentum is the traction's impulse times the end's area (the trapezoidal
    rule is exact on a linear load)."""
    import yaml

    import fem_impact as fi

    data = {"name": "pulled", "parameters": {"p": 3.0},
            "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.1, "cells": 10},
            "material": {"E": 100.0, "rho": 1.0, "nu": 0.3, "area": 0.5},
            "loads": [{"nodes": "right", "traction": ["p*t", 2.0]}],
            "solver": {"dt": 0.01, "t_end": 0.5}, "output": {"vtk": False}}
    result = fi.run(fi.Case.from_dict(data), tmp_path / "out")
    resolved = yaml.safe_load((tmp_path / "out" / "case.resolved.yaml").read_text())
    assert resolved["loads"][0]["traction"][0] == "p*t"
    t, area = result.history["t"][-1], 0.1 * 0.5
    assert result.history["bar.px"][-1] == pytest.approx(0.5 * 3.0 * t * t * area, rel=1e-9)
    assert result.history["bar.py"][-1] == pytest.approx(2.0 * t * area, rel=1e-9)
