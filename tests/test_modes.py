"""Natural modes (fem_impact.fem.modes, ``fem-impact modes``) against closed-form frequencies.

Rods (1D, E = rho = A = 1, L = 1, c = 1): free-free f_k = k c / (2L) after one rigid-body
mode, clamped-free f_k = (2k - 1) c / (4L). P1 elements with a consistent mass matrix give
frequencies from above with an O(h^2) error.

Cantilevers (built-in bar, L = 1, h = L/20, nu = 0, clamped at `left`) against the
Euler-Bernoulli f1 = (1.87510407^2 / 2 pi) sqrt(E I / (rho A L^4)), I / A = h^2 / 12 for both
the 2D plane-stress strip and the 3D box (bending in y). Linear triangles and tetrahedra lock
in bending: the error is large on coarse meshes (37 % with two triangles through the
thickness) and falls as h^2. Measured (E = rho = 1, f_EB = 0.0080773):
  2D, 80/160/320 cells along (4/8/16 across): errors 10.2 %, 2.53 %, 0.52 %, fitted order 2.15
  3D (width h/2), 40/80/160 along (2/4/8 across in y): errors 38.6 %, 10.3 %, 2.53 %, order 1.97
The 2D order is a little above 2 because the 2D (Timoshenko-like) beam is about 0.17 %
more flexible than Euler-Bernoulli, which offsets the discretization error on the finest
mesh; successive differences of the frequencies alone give orders 1.93 and 1.98.
"""

from __future__ import annotations

import csv
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from mpi4py import MPI

from conftest import CASES, run_cli

C_EB = 1.87510407**2 / (2.0 * np.pi)


def analyse(name: str, n: int, *overrides: str, **kwargs):
    """(modes, model) of a case file in this process."""
    from fem_impact.build import finite_element_model
    from fem_impact.config.case import load_case
    from fem_impact.fem.modes import compute_modes

    case = load_case(CASES / f"{name}.yaml", ["contacts=[]", *overrides])
    model = finite_element_model(case, MPI.COMM_SELF)
    return compute_modes(model, n, **kwargs), model


def gram(modes, model) -> np.ndarray:
    """Y^T M Y with the model's own mass matrix."""
    x, y = model.M.createVecs()
    MY = np.empty_like(modes.Y_local)
    for i in range(modes.n):
        x.array[:] = modes.Y_local[:, i]
        model.M.mult(x, y)
        MY[:, i] = y.array_r
    return modes.Y_local.T @ MY


def order(sizes, errors) -> float:
    """Slope of log(error) against log(h) (least squares)."""
    return float(np.polyfit(np.log(sizes), np.log(errors), 1)[0])


# ---------------------------------------------------------------------------------------
# Rods

ROD_CELLS = (40, 80, 160)


@pytest.mark.parametrize("name, exact, rigid", [
    ("impacting_bar", lambda k: k / 2.0, 1),             # free-free
    ("signorini_bar", lambda k: (2 * k - 1) / 4.0, 0),   # clamped (right) - free
])
def test_rod_frequencies_converge_as_h_squared(name, exact, rigid):
    from fem_impact.fem.modes import participation

    k = np.arange(1, 6)
    f_exact = exact(k)
    errors = []
    for cells in ROD_CELLS:
        modes, model = analyse(name, 5 + rigid, f"mesh.cells={cells}")
        assert modes.n_rigid == rigid and modes.rigid[:rigid].all()
        assert np.all(modes.omega2[:rigid] == 0.0)
        f = modes.frequency_hz[rigid:]
        errors.append(f / f_exact - 1.0)
        assert np.abs(gram(modes, model) - np.eye(modes.n)).max() < 1e-10
        assert modes.residual.max() < 1e-9
        mass = participation(modes, model)[:, 0]
        if rigid:  # the translation carries all the mass, elastic modes none of it
            assert mass[0] == pytest.approx(1.0, abs=1e-12) and np.abs(mass[1:]).max() < 1e-12
        else:  # clamped-free rod: 8 / ((2k - 1) pi)^2, to O(h): the fractions are of the mass of
            # the free dofs, without the share of the clamped node (h/3 of the rod's mass)
            exact_mass = 8.0 / ((2 * k - 1) * np.pi) ** 2
            assert np.abs(mass / exact_mass - 1.0).max() < 1.2 / cells
    errors = np.array(errors)                 # meshes x modes
    assert np.all(errors > 0)                 # consistent mass: from above
    assert np.all(np.diff(errors, axis=0) < 0)
    for j in range(5):
        assert order(1.0 / np.array(ROD_CELLS), errors[:, j]) == pytest.approx(2.0, abs=0.2), f"mode {j + 1}"
    assert errors[-1].max() < 2e-3


# ---------------------------------------------------------------------------------------
# Cantilevers

def cantilever(dim: int, cells: int, width: float) -> float:
    """f1 of the y-bending mode of the clamped built-in bar, L = 1, h = 0.05, nu = 0."""
    from fem_impact.fem.modes import participation

    fix = "[x, y]" if dim == 2 else "[x, y, z]"
    modes, model = analyse("impacting_bar", 3, "initial={}", f"mesh.dim={dim}", f"mesh.cells={cells}",
                           "mesh.height=0.05", *([f"mesh.width={width}"] if dim == 3 else []), "material.nu=0.0",
                           f"supports=[{{nodes: left, fix: {fix}}}]")
    assert modes.n_rigid == 0
    assert np.abs(gram(modes, model) - np.eye(modes.n)).max() < 1e-10
    mass = participation(modes, model)
    i = int(np.argmax(mass[:, 1]))            # the mode that bends in y
    assert mass[i, 1] > 0.5                   # 61 % for an Euler-Bernoulli cantilever
    return float(modes.frequency_hz[i])


@pytest.mark.parametrize("dim, cells, width, finest", [
    (2, (80, 160, 320), 1.0, 0.01),       # width unused in 2D (material.area is the thickness)
    (3, (40, 80, 160), 0.025, 0.03),      # width h/2: the y-bending mode is the second one
])
def test_cantilever_against_euler_bernoulli(dim, cells, width, finest):
    f_eb = C_EB * np.sqrt(0.05**2 / 12.0)
    errors = np.array([cantilever(dim, n, width) / f_eb - 1.0 for n in cells])
    assert np.all(errors > 0) and np.all(np.diff(errors) < 0)
    assert order(1.0 / np.array(cells), errors) == pytest.approx(2.0, abs=0.3)
    assert errors[-1] < finest


# ---------------------------------------------------------------------------------------
# Free bodies, checks and limits

@pytest.mark.parametrize("dim, rigid", [(2, 3), (3, 6)])
def test_free_body_rigid_modes(dim, rigid):
    from fem_impact.fem.modes import participation

    modes, model = analyse("impacting_bar", rigid + 2, f"mesh.dim={dim}", "mesh.cells=40")
    assert modes.n_rigid == rigid and modes.rigid[:rigid].all() and not modes.rigid[rigid:].any()
    assert np.all(modes.frequency_hz[:rigid] == 0.0) and modes.frequency_hz[rigid] > 0.01
    assert np.abs(gram(modes, model) - np.eye(modes.n)).max() < 1e-10
    # The rigid subspace is ordered: translations x, y (, z) first.
    mass = participation(modes, model)
    assert mass[:dim] == pytest.approx(np.eye(dim), abs=1e-10)
    assert np.abs(mass[dim:]).max() < 1e-10


SQUARE_CANTILEVER = ["initial={}", "mesh.dim=3", "mesh.cells=40", "mesh.height=0.05", "mesh.width=0.05",
                     "material.nu=0.0", "supports=[{nodes: left, fix: [x, y, z]}]"]


def split_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "inside a multiple eigenvalue" in r.getMessage()]


@pytest.mark.parametrize("elements, n, warned", [("hex", 1, True), ("hex", 2, False), ("simplex", 1, False)])
def test_modes_that_split_a_multiple_eigenvalue_are_warned_of(caplog, elements, n, warned):
    """A square-section cantilever of hexahedra bends alike in y and z: its first frequency is double
    (to 5e-11). One mode keeps a vector of that plane which round-off chooses: a warning; two keep the
    plane. Tetrahedra break the symmetry (the two frequencies 14 % apart): no warning."""
    from fem_impact.fem.modes import warn_if_split

    modes, _ = analyse("impacting_bar", 3, *SQUARE_CANTILEVER, f"mesh.elements={elements}")
    with caplog.at_level("WARNING", logger="fem_impact.fem.modes"):
        warn_if_split(modes, n)
    said = split_warnings(caplog)
    assert bool(said) == warned, said
    if warned:
        assert said[0].startswith("modes: the 1 modes kept end inside a multiple eigenvalue (modes 1 and 2")


def test_a_reduced_model_on_one_mode_of_a_double_frequency_warns(caplog):
    """The reduced model kept on one mode of the square hexahedral cantilever says so as it is built."""
    from fem_impact.config.case import load_case
    import fem_impact as fi

    case = load_case(CASES / "impacting_bar.yaml", ["contacts=[]", *SQUARE_CANTILEVER, "mesh.elements=hex",
                                                    "solver.method=modal", "solver.modes=1", "solver.dt=0.01",
                                                    "solver.t_end=0.05", "output.vtk=false"])
    with caplog.at_level("WARNING", logger="fem_impact.fem.modes"):
        fi.run(case)   # (nothing written: the history in memory)
    assert split_warnings(caplog)


def test_missed_mode_is_an_error():
    from fem_impact.fem.modes import ModesError, _check_count

    modes, model = analyse("impacting_bar", 5, "mesh.cells=20")
    _check_count(model.K, model.M, modes.omega2, MPI.COMM_SELF)   # no supports: the full matrices
    with pytest.raises(ModesError, match="missed 1 mode"):
        _check_count(model.K, model.M, np.delete(modes.omega2, 2), MPI.COMM_SELF)


def test_mode_count_limits():
    from fem_impact.fem.modes import ModeCountError

    with pytest.raises(ModeCountError, match="at least 1"):
        analyse("signorini_bar", 0, "mesh.cells=4")
    with pytest.raises(ModeCountError, match="only 4 free dofs"):
        analyse("signorini_bar", 5, "mesh.cells=4")
    modes, _ = analyse("signorini_bar", 3, "mesh.cells=4")   # the most the Krylov solver finds
    assert modes.n == 3 and modes.residual.max() < 1e-9
    modes, _ = analyse("signorini_bar", 4, "mesh.cells=4")   # all of them: the dense solver
    assert modes.n == 4 and modes.residual.max() < 1e-9
    # Clamped-free rod of 4 cells: the exact discrete spectrum is that of the dense problem.
    assert modes.frequency_hz[0] == pytest.approx(1 / 4, rel=0.02)


# ---------------------------------------------------------------------------------------
# The command

def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_cli_writes_table_csv_and_pvd(tmp_path):
    out = tmp_path / "modes"
    result = run_cli("modes", str(CASES / "signorini_bar.yaml"), "-n", "4", "-o", str(out),
                     "--set", "mesh.cells=20")
    assert result.returncode == 0, result.stderr
    assert "mass x [%]" in result.stdout and "elastic" in result.stdout
    rows = read_csv(out / "modes.csv")
    assert [r["mode"] for r in rows] == ["1", "2", "3", "4"]
    # (the earlier columns keep their places; `moves` describes each mode)
    assert list(rows[0]) == ["mode", "frequency_hz", "type", "mass_x_percent", "residual", "moves"]
    assert all(r["moves"] == "longitudinal: bar 100 %; x 100 %" for r in rows)
    f = np.array([float(r["frequency_hz"]) for r in rows])
    assert f == pytest.approx((2 * np.arange(1, 5) - 1) / 4.0, rel=0.02)
    pvd = (out / "modes.pvd").read_text()
    assert re.findall(r'timestep="([^"]+)"', pvd) == ["1", "2", "3", "4"]
    assert len(list(out.glob("*.vtu"))) == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["modes"]   # no staging folder left


def test_cli_default_folder_and_free_body(tmp_path):
    result = run_cli("modes", str(CASES / "impacting_bar.yaml"), "--set", "mesh.cells=20", "-q", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout == ""
    rows = read_csv(tmp_path / "results" / "impacting_bar-modes" / "modes.csv")
    assert len(rows) == 10                    # the default count
    assert rows[0]["type"] == "rigid" and float(rows[0]["frequency_hz"]) == 0.0
    assert float(rows[0]["mass_x_percent"]) == pytest.approx(100.0)


@pytest.mark.parametrize("args, message", [
    (["-n", "0"], "-n 0: ask for at least 1 mode"),
    (["-n", "21"], "-n 21: asked for 21 modes but the model has only 20 free dofs; ask for at most 20"),
    (["--set", "solver.method=modal", "--set", "solver.modes=30"], "solver.modes: asked for 30 modes"),
    (["--set", "mesh.cells=0"], "mesh.cells"),
])
def test_cli_bad_counts(tmp_path, args, message):
    out = tmp_path / "modes"
    result = run_cli("modes", str(CASES / "signorini_bar.yaml"), "-o", str(out), "--set", "mesh.cells=20", *args)
    assert result.returncode == 2
    assert message in result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.mpi
@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_cli_two_ranks_agree(tmp_path):
    args = ["modes", str(CASES / "impacting_bar.yaml"), "-n", "6", "-q", "--set", "mesh.dim=2",
            "--set", "mesh.cells=60", "--set", "supports=[{nodes: left, fix: [x, y]}]"]
    serial = run_cli(*args, "-o", str(tmp_path / "serial"))
    assert serial.returncode == 0, serial.stderr
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "OPAL_"))}
    parallel = subprocess.run(["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable,
                               "-m", "fem_impact", *args, "-o", str(tmp_path / "mpi")],
                              capture_output=True, text=True, env=env)
    assert parallel.returncode == 0, parallel.stderr
    a, b = read_csv(tmp_path / "serial" / "modes.csv"), read_csv(tmp_path / "mpi" / "modes.csv")
    for ra, rb in zip(a, b, strict=True):
        assert ra["type"] == rb["type"]
        for key in ("frequency_hz", "mass_x_percent", "mass_y_percent"):
            assert float(ra[key]) == pytest.approx(float(rb[key]), rel=1e-8, abs=1e-8)
    assert len(list((tmp_path / "mpi").glob("*_p1_*.vtu"))) == 6


def test_failed_computation_leaves_no_output(tmp_path, monkeypatch, capsys):
    import fem_impact.fem.modes as fm
    from fem_impact.app.cli import _modes, build_parser

    monkeypatch.setattr(fm, "RESIDUAL_LIMIT", 1e-30)
    out = tmp_path / "modes"
    args = build_parser().parse_args(["modes", str(CASES / "signorini_bar.yaml"), "-n", "3", "-o", str(out),
                                      "--set", "mesh.cells=20"])
    assert _modes(args) == 3
    err = capsys.readouterr().err
    assert "the modal analysis failed: mode 1 has a relative residual" in err
    assert "0 of the 3 modes are within it" in err
    assert list(tmp_path.iterdir()) == []


def test_modal_mass_at_the_tip_of_the_clamped_free_rod(tmp_path):
    """``modes --at right --direction x``: for the clamped-free rod (rho = 1.5, A = 0.5, L = 2) mode i is
    y = sqrt(2 / (rho A L)) sin((2i - 1) pi x / (2 L)), so each mode's modal mass at the tip is rho A L / 2
    (0.75), its stiffness w_i^2 rho A L / 2, and its participation factor Gamma_i = +-sqrt(2 rho A L) 2 /
    ((2i - 1) pi); the description says it is longitudinal."""
    case = tmp_path / "rod.yaml"
    case.write_text("name: rod\nmesh: {shape: bar, dim: 1, length: 2.0, cells: 400}\n"
                    "material: {E: 3.0, rho: 1.5, area: 0.5}\nsupports: [{nodes: left, fix: [x]}]\n"
                    "solver: {dt: 0.01, t_end: 0.1}\n")
    result = run_cli("modes", str(case), "--at", "right", "--direction", "x", "-n", "3", "-o", str(tmp_path / "m"))
    assert result.returncode == 0, result.stderr
    rows = list(csv.DictReader(open(tmp_path / "m" / "modes.csv")))
    c, L, mass = np.sqrt(3.0 / 1.5), 2.0, 1.5 * 0.5 * 2.0
    for i, row in enumerate(rows, start=1):
        w = (2 * i - 1) * np.pi * c / (2 * L)
        assert float(row["right.x.modal_mass"]) == pytest.approx(mass / 2, rel=1e-3)
        assert float(row["right.x.modal_stiffness"]) == pytest.approx(w**2 * mass / 2, rel=2e-3 * i)
        assert abs(float(row["participation_x"])) == pytest.approx(np.sqrt(2 * mass) * 2 / ((2 * i - 1) * np.pi),
                                                                    rel=1e-3)
        assert row["moves"].startswith("longitudinal: bar 100 %")
    assert "modal mass" in result.stdout
    bad = run_cli("modes", str(case), "--at", "tip", "-o", str(tmp_path / "bad"))
    assert bad.returncode != 0 and "no node group 'tip'" in bad.stderr and "Traceback" not in bad.stderr
    bad = run_cli("modes", str(case), "--at", "right", "--direction", "y", "-o", str(tmp_path / "bad"))
    assert bad.returncode != 0 and "--direction: y: the model is 1D" in bad.stderr


def test_the_modes_of_a_2d_cantilever_are_described():
    """A 2D strip clamped at one end: its first modes bend (transverse, y), the first along x is longitudinal."""
    from fem_impact.build import finite_element_model
    from fem_impact.fem.modes import compute_modes, describe
    import fem_impact as fi

    case = fi.Case.from_dict({"name": "strip", "material": {"E": 1.0, "rho": 1.0}, "solver": {"dt": 0.1, "t_end": 1},
                              "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.05, "cells": 100},
                              "supports": [{"nodes": "left", "fix": "all"}]})
    model = finite_element_model(case, MPI.COMM_WORLD)
    words = describe(compute_modes(model, 6), model)
    assert words[0].startswith("transverse (y): bar 100 %; y ")
    assert any(w.startswith("longitudinal: bar 100 %; x ") for w in words)


def test_an_axisymmetric_model_has_an_effective_mass_along_its_axis_only(tmp_path):
    """A uniform radial displacement is a ring's expansion, not a translation: the table and modes.csv give
    no radial effective mass (they printed one, meaningless), nor a radial participation factor; along
    the axis, the free disk's rigid translation carries all of its mass."""
    from fem_impact.app.modes import format_table, run_modes

    case = tmp_path / "disk.yaml"
    case.write_text("name: disk\nmesh: {shape: bar, dim: 2, length: 1.0, height: 0.2, cells: 10, "
                    "hypothesis: axisymmetric}\nmaterial: {E: 1.0, rho: 1.0, nu: 0.3}\n"
                    "solver: {dt: 0.01, t_end: 0.1}\n")
    summary = run_modes(case, tmp_path / "m", n=4)
    assert summary["columns"][3:5] == ["mass_y_percent", "residual"]   # (axis y: the radius is x)
    rows = read_csv(tmp_path / "m" / "modes.csv")
    assert "mass_x_percent" not in rows[0]
    assert rows[0]["type"] == "rigid" and float(rows[0]["mass_y_percent"]) == pytest.approx(100.0, rel=1e-9)
    table = format_table(summary)
    assert "mass y [%]" in table and "mass x [%]" not in table and "along the axis y only" in table
    radial = run_modes(case, tmp_path / "r", n=4, at="right", direction="x")
    assert not any(c.startswith("participation") for c in radial["columns"])
    assert "no Gamma: x is the radius" in format_table(radial)
    axial = run_modes(case, tmp_path / "a", n=4, at="top", direction="y")
    assert axial["columns"][-1] == "participation_y"
    # plane models keep every direction
    plane = tmp_path / "plate.yaml"
    plane.write_text(case.read_text().replace(", hypothesis: axisymmetric", "").replace("name: disk", "name: plate"))
    assert run_modes(plane, tmp_path / "p", n=3)["columns"][3:5] == ["mass_x_percent", "mass_y_percent"]
