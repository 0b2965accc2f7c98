"""Contact that never creates energy, at any step, on faces of many rows (issue 10).

The mechanism, on two masses: the paper's scheme (trapezoidal Newmark, position-level
multipliers) books the contact forces with the trapezoidal weights, so a step's contact work on
the structure is ``-Delta(P U) . (F_n + F_n+1)/2 = (F_n . g_n+1 - F_n+1 . g_n)/2`` (complementarity
``F . g = 0`` at both ends, ``g = d0 - P U``): a row that carried a force at t_n and is open at
t_n+1 *gives* ``F_n g_n+1 / 2``. Far above the Courant limit the stiff modes ring with period
2 dt, rows open and close every step and those terms win. Moreau-Jean (the default) applies the
contact as an impulse with the mean velocity of the step: its work is ``p (1 - e) gdot_n / 2 <= 0``.

The family: 1, 4, 11 and 49 rows; Courant numbers 0.5 to 50; restitution 0, 0.5 and 1; 1D, 2D,
3D; full and reduced model; Moreau-Jean at the position level (the default) and at the velocity
level; elastic stops up to 1e12 N/m; mass redistribution. With the default method the energy never
exceeds ``E0 + W_ext(t)`` by more than 1e-6 of the energy scale, and no loss goes below zero.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import CASES, ConstantLoad, run_case_file, run_cli
from fem_impact import Case
from fem_impact.integrators import EnergyWatch, MoreauJean, Newmark, Operators, integrate

TOL = 1e-6
FACE = ["contacts.0.stiffness=null", "contacts.0.coupling=each"]   # beam_stop: 11 rigid rows under the tip section
REPRODUCTION = [*FACE, "solver.dt=2e-3", "solver.t_end=2"]        # issue 10's reproduction (Courant about 12)


def energy_excess(h) -> tuple[float, float]:
    """(largest ``E - E0 - W_ext(t)``, most negative loss), both relative to ``max (E0 + W_ext)``."""
    E = h["kinetic"] + h["strain"]
    bound = E[0] + h["external_work"]
    scale = max(bound.max(), E[0])
    worst_loss = min((h["contact_loss"] + h["impact_loss"]).min(), h["damping_loss"].min(), 0.0)
    return float((E - bound).max() / scale), float(-worst_loss / scale)


def assert_holds(summary, h):
    excess, loss = energy_excess(h)
    assert excess <= TOL, f"E exceeded E0 + W_ext by {excess:.3g} of the energy scale"
    assert loss <= TOL, f"a loss went below zero by {loss:.3g} of the energy scale"
    assert summary["energy_created_at"] is None and summary["energy_created"] == 0.0


# --- the mechanism, on two masses -----------------------------------------------------------

def two_masses(restitution=0.0):
    """Unit masses joined by a spring k = 1e4 (omega = 141), the first against a wall 0.1 away,
    the second pushed toward it by a unit force."""
    K = 1e4 * np.array([[1.0, -1.0], [-1.0, 1.0]])
    return Operators(np.eye(2), K, None, ConstantLoad(np.array([0.0, 1.0])), np.array([[1.0], [0.0]]),
                     np.array([0.1]), np.array([restitution]))


class Steps:
    def __init__(self):
        self.rows = []

    def write(self, s):
        e = s.energy
        self.rows.append((s.gap[0], s.force[0], e.total, e.initial + e.external_work, e.contact_loss, e.impact_loss))

    def array(self):
        return np.array(self.rows)


@pytest.mark.parametrize("dt", [0.1, 0.2])   # omega dt = 14 and 28
def test_release_work_of_position_level_forces_creates_the_energy(dt):
    """The paper's scheme on two masses: its contact work per step is
    ``(F_n g_n+1 - lam0_n+1 g_n)/2`` (lam0: the position-level force, before the acceleration
    projection): on a step that ends open exactly the release term ``F_n g_n+1 / 2 >= 0``, on one
    that ends closed at most zero. The releases outweigh Carnot's loss and the energy ends far
    above what the load put in. Moreau-Jean on the same steps stays below."""
    record = Steps()
    integrate(Newmark(two_masses(), dt), np.zeros(2), np.zeros(2), 400 * dt, [record],
              watch=EnergyWatch(blow_up=np.inf))   # (at omega dt = 28 it passes 100 times E0 + W_ext by step 185)
    gap, force, E, bound, contact_loss, impact_loss = record.array().T
    given = -np.diff(contact_loss)                                   # work given to the structure per step
    opens = gap[1:] > 1e-12
    release = 0.5 * force[:-1] * gap[1:]
    np.testing.assert_allclose(given[opens], release[opens], atol=1e-12 * bound.max())
    assert np.all(given[~opens] <= 1e-12 * bound.max())
    assert np.count_nonzero(release[opens] > 0) >= 5                # rows carrying a force open, again and again
    # The balance closes, so what E gains over E0 + W_ext is what the contacts gave: the releases.
    np.testing.assert_allclose(E - bound, -(contact_loss + impact_loss), atol=1e-12 * bound.max())
    assert E.max() > 1.5 * bound.max()

    record = Steps()
    integrate(MoreauJean(two_masses(), dt), np.zeros(2), np.zeros(2), 400 * dt, [record])
    _, _, E, bound, contact_loss, _ = record.array().T
    assert np.all(np.diff(contact_loss) >= -1e-12 * bound.max())     # every step loses, never gives
    assert E.max() <= bound.max() * (1 + TOL)


@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
def test_two_masses_hold_for_every_restitution_at_any_step(e):
    for dt in (1e-3, 0.03, 1.0):
        record = Steps()
        integrate(MoreauJean(two_masses(e), dt), np.zeros(2), np.zeros(2), 300 * dt, [record])
        _, _, E, bound, contact_loss, _ = record.array().T
        assert np.all(np.diff(contact_loss) >= -1e-12 * bound.max())
        assert np.all(E <= bound * (1 + TOL) + TOL * bound.max())


# --- the reproduction of issue 10 and the paper's scheme failing on it --------------------------

def test_default_method_is_one_that_holds():
    case = Case.from_dict({"mesh": {"shape": "bar"}, "material": {"E": 1.0, "rho": 1.0},
                           "solver": {"dt": 1.0, "t_end": 1.0}})
    assert case.solver.method == "moreau_jean"


def test_reproduction_holds_with_the_default_method(tmp_path):
    """beam_stop's tip section, 11 rigid rows, Courant about 12: the default method stays below
    E0 + W_ext (the paper's scheme: 7.9 times above, below)."""
    summary, h = run_case_file(CASES / "beam_stop.yaml", tmp_path, *REPRODUCTION, "solver.method=moreau_jean",
                               "output.vtk=false")
    assert summary["constraints"] == 11
    assert_holds(summary, h)
    assert summary["max_energy_error_relative"] < 1e-9          # and the balance closes
    assert summary["max_energy_ratio"] <= 1.0 + TOL


def test_paper_scheme_creates_energy_there_and_the_warning_fires(tmp_path):
    """The same run with the paper's scheme: energy created (summary), a warning on stderr with
    the figure and the time it began, status 0; with --stop-on-energy-gain, status 3."""
    args = ["run", str(CASES / "beam_stop.yaml"), "-q", "--set", "output.vtk=false", "--set", "solver.method=newmark"]
    for o in REPRODUCTION:
        args += ["--set", o]
    proc = run_cli(*args, "-o", str(tmp_path / "paper"))
    assert proc.returncode == 0, proc.stderr
    assert "warning: the contacts created energy" in proc.stderr and "first at t = " in proc.stderr
    import json
    summary = json.loads((tmp_path / "paper" / "summary.json").read_text())
    assert summary["max_energy_ratio"] > 5.0 and summary["energy_created_relative"] > 1.0
    assert summary["energy_created_at"] > 0.0
    proc = run_cli(*args, "-o", str(tmp_path / "strict"), "--stop-on-energy-gain")
    assert proc.returncode == 3 and "created energy" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "strict").exists()


# --- the family -----------------------------------------------------------------------------

# 2D: beam_stop coarsened to 20 cells along (3 across: 4 rows at the tip), c = 105 m/s, h = 0.05 m.
BEAM = ["mesh.cells=20", "output.vtk=false", *FACE]
# 3D: a box 1 x 0.3 x 0.3 falling on its face (7 x 7 = 49 rows), pulled toward the wall by a
# body acceleration so that it keeps landing; c = 1, h = 0.05.
BOX = ["mesh.dim=3", "mesh.cells=20", "mesh.height=0.3", "mesh.width=0.3", "output.vtk=false",
       "loads=[{body: all, acceleration: [-1.0, 0, 0]}]", "output.probes={}"]


def courant_dt(courant, c, h):
    return courant * h / c


@pytest.mark.parametrize("level", ["position", "velocity"])
@pytest.mark.parametrize("model", ["full", "reduced"])
@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("courant", [0.5, 5.0, 50.0])
def test_face_of_a_2d_beam_holds(tmp_path, courant, e, model, level):
    dt = courant_dt(courant, 105.0, 0.05)
    extra = ["solver.method=modal", "solver.modes=10"] if model == "reduced" else ["solver.method=moreau_jean"]
    summary, h = run_case_file(CASES / "beam_stop.yaml", tmp_path, *BEAM, f"contacts.0.restitution={e}",
                               f"solver.dt={dt}", f"solver.t_end={max(0.3, 40 * dt)}", f"solver.level={level}",
                               *extra)
    assert summary["constraints"] == 4
    assert_holds(summary, h)
    assert h["stop_impulse"].sum() > 0.0


@pytest.mark.parametrize("model, level", [("full", "position"), ("full", "velocity"), ("reduced", "position")])
@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("courant", [0.5, 50.0])
def test_face_of_a_3d_box_holds(tmp_path, courant, e, model, level):
    dt = courant_dt(courant, 1.0, 0.05)
    extra = ["solver.method=modal", "solver.modes=12"] if model == "reduced" else ["solver.method=moreau_jean"]
    summary, h = run_case_file(CASES / "impacting_bar.yaml", tmp_path, *BOX, f"contacts.0.restitution={e}",
                               f"solver.dt={dt}", f"solver.t_end={max(6.0, 40 * dt)}", f"solver.level={level}",
                               *extra)
    assert summary["constraints"] == 49
    assert_holds(summary, h)
    assert h["wall_impulse"].sum() > 0.0


@pytest.mark.parametrize("level", ["position", "velocity"])
@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("courant", [0.5, 50.0])
def test_one_row_1d_bar_holds(tmp_path, courant, e, level):
    """B2a's rod pressed on the wall by a body acceleration: one row, many impacts."""
    dt = courant_dt(courant, 1.0, 1.0 / 50)
    summary, h = run_case_file(CASES / "impacting_bar.yaml", tmp_path, "mesh.cells=50", f"solver.dt={dt}",
                               f"solver.t_end={max(6.0, 40 * dt)}", f"contacts.0.restitution={e}",
                               "solver.method=moreau_jean", f"solver.level={level}",
                               "loads=[{body: all, acceleration: [-1.0]}]", "output.vtk=false")
    assert_holds(summary, h)
    assert h["wall_impulse"].sum() > 0.0


@pytest.mark.parametrize("stiffness", [1e5, 1e8, 1e12])
@pytest.mark.parametrize("courant", [0.5, 50.0])
def test_elastic_stops_on_a_steel_bar_hold(tmp_path, stiffness, courant):
    """B2b's steel bar (EA/L = 6.6e7 N/m) pressed on a stop of 1e5 to 1e12 N/m by a body acceleration."""
    c, h_el = np.sqrt(210e9 / 7800), 1.0 / 100
    dt = courant_dt(courant, c, h_el)
    summary, h = run_case_file(CASES / "impacting_bar_steel.yaml", tmp_path, "mesh.cells=100",
                               f"contacts.0.stiffness={stiffness}", f"solver.dt={dt}",
                               f"solver.t_end={max(1.5e-3, 40 * dt)}", "solver.method=moreau_jean",
                               "loads=[{body: all, acceleration: [-2000.0]}]", "output.vtk=false")
    assert_holds(summary, h)
    assert summary["max_stop_compression"] > 0.0


@pytest.mark.parametrize("stiffness", [1e5, 1e8])
def test_paper_scheme_on_stiff_elastic_stops_is_flagged(tmp_path, stiffness):
    """Issue 10, point 2: the default bar on a stiff stop, the paper's scheme: energy created, said."""
    summary, _ = run_case_file(CASES / "impacting_bar.yaml", tmp_path, "mesh.cells=50", "solver.dt=0.01",
                               f"contacts.0.stiffness={stiffness}", "output.vtk=false")
    assert summary["method"] == "newmark" and summary["energy_created_at"] is not None
    summary, h = run_case_file(CASES / "impacting_bar.yaml", tmp_path / "mj", "mesh.cells=50", "solver.dt=0.01",
                               f"contacts.0.stiffness={stiffness}", "output.vtk=false", "solver.method=moreau_jean")
    assert_holds(summary, h)


def test_mass_redistribution_holds_with_the_default_method(tmp_path):
    """Mass redistribution on the face (massless contact nodes): the paper's scheme creates
    energy there by the same release work (no Carnot correction on a massless row to take it
    back); Moreau-Jean's energy argument needs no mass on the rows and holds."""
    common = [*REPRODUCTION, "solver.mass=redistributed", "output.vtk=false"]
    paper, _ = run_case_file(CASES / "beam_stop.yaml", tmp_path / "paper", *common)
    assert paper["energy_created_relative"] > 1.0
    summary, h = run_case_file(CASES / "beam_stop.yaml", tmp_path / "mj", *common, "solver.method=moreau_jean")
    assert_holds(summary, h)
