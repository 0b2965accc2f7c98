"""The reduced model (docs/theory.md s. 8): all modes = the full model; the static correction keeps
contact right with few modes; truncation alone does not; the residual flexibility is exact."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import scipy.linalg
from mpi4py import MPI

from conftest import CASES, b2_checks, run_case_file, run_cli
from fem_impact.build import model_and_constraints
from fem_impact.config.case import load_case
from fem_impact.fem.modes import compute_modes
from fem_impact.fem.reduced import build_reduced
from test_bar_benchmarks import B2A, assert_b2

BAR = CASES / "impacting_bar.yaml"


@pytest.mark.parametrize("case, extra", [
    ("impacting_bar", ["mesh.cells=12", "solver.dt=0.04"]),                 # free body: a rigid mode
    ("signorini_bar", ["mesh.cells=12", "solver.dt=0.04", "solver.t_end=4"]),  # clamped
    ("impacting_bar", ["mesh.cells=12", "solver.dt=0.04", "contacts.0.stiffness=20"]),  # elastic stop
])
def test_all_modes_reproduce_the_full_model(tmp_path, case, extra):
    """With every mode kept S_k = 0: the same Newmark steps in another basis, to round-off."""
    common = [*extra, "output.vtk=false"]
    _, full = run_case_file(CASES / f"{case}.yaml", tmp_path / "full", *common)
    summary, red = run_case_file(CASES / f"{case}.yaml", tmp_path / "red", *common, "solver.method=modal",
                                 "solver.scheme=newmark", f"solver.modes={12 if case == 'signorini_bar' else 13}")
    assert summary["modes"] in (12, 13)
    energy = full["kinetic"][0] + full["strain"][0]
    for name in full.dtype.names:
        # (the balance residual is round-off itself: compared on the scale of the energy)
        scale = energy if name == "energy_error" else max(np.abs(full[name]).max(), 1e-12)
        assert np.abs(full[name] - red[name]).max() <= 1e-9 * scale, name
    assert np.abs(full["left_ux"]).max() > 0.05   # something happened


@pytest.mark.parametrize("n1", [10, 20])
def test_static_correction_meets_the_b2a_tolerances_with_few_modes(tmp_path, n1):
    summary, h = run_case_file(BAR, tmp_path, "solver.method=modal", f"solver.modes={n1}", "output.vtk=false")
    assert_b2(h)
    assert summary["modes"] == n1 and summary["rigid_modes"] == 1
    assert summary["max_energy_error_relative"] < 1e-9
    # The compliant contact releases its last force over a step that the scheme does not
    # resolve: it hands back a little energy (measured 3.1e-5 of E0 at 10 modes, 1.7e-5 at
    # 20), booked as a negative contact loss, never more than that.
    e = h["kinetic"] + h["strain"]
    assert e.max() <= e[0] * (1 + 1e-4)
    assert -h["contact_loss"].min() < 1e-4 * e[0]
    # The neglected flexibility at the wall shrinks as modes are added (about 0.6 / n1 here).
    assert 0.2 / n1 < summary["neglected_flexibility"]["wall"] < 1.0 / n1


def test_truncation_without_static_correction_leaves_an_error(tmp_path):
    """Plain truncation to 10 modes misses the force, the impulse and the rebound by several %."""
    _, h = run_case_file(BAR, tmp_path, "solver.method=modal", "solver.scheme=newmark", "solver.modes=10",
                         "solver.static_correction=false", "output.vtk=false")
    errors = b2_checks(h, **B2A)
    assert errors["mean_force"] > 0.04 and errors["rebound"] > 0.04 and errors["impulse"] > 0.02


@pytest.mark.parametrize("overrides", [
    ["mesh.cells=16"],                                                        # free rod
    ["mesh.cells=16", "supports=[{nodes: right, fix: [x]}]"],                 # clamped rod
    ["mesh.dim=2", "mesh.cells=8", "mesh.height=0.25"],                       # free strip: 3 rigid modes
])
def test_residual_flexibility_matches_a_dense_eigendecomposition(overrides):
    """P S_k P^T from static solves (inertia relief for free bodies) equals the sum over the
    truncated elastic modes of a dense eigendecomposition, P Y2 diag(1/w2^2) Y2^T P^T."""
    case = load_case(BAR, overrides)
    model, cons = model_and_constraints(case, MPI.COMM_SELF)
    n1 = 5
    red = build_reduced(model, cons, compute_modes(model, n1), n1, True, 0.0, 0.0, 0.01)

    free = np.setdiff1d(np.arange(model.dofs), model.fixed)
    K = model.K.convert("dense").getDenseArray()[np.ix_(free, free)]
    M = model.M.convert("dense").getDenseArray()[np.ix_(free, free)]
    w2, Y = scipy.linalg.eigh(K, M)
    P = cons.P_local.toarray()[free].T
    truncated = slice(n1, None)
    exact = (P @ Y[:, truncated]) @ np.diag(1 / w2[truncated]) @ (P @ Y[:, truncated]).T
    np.testing.assert_allclose(red.static.compliance, exact, rtol=1e-8, atol=1e-12 * np.abs(exact).max())
    assert np.abs(exact).max() > 0


@pytest.mark.parametrize("overrides, message", [
    (["solver.modes=300"], "solver.modes: asked for 300 modes but the model has only 51 free dofs"),
    (["mesh.dim=2", "mesh.cells=20", "solver.modes=2"], "rigid-body modes: keep them all (modes >= 3)"),
    (["solver.tolerance=1.5"], "solver.tolerance: must be in (0, 1), got 1.5"),
    (["solver.modes=0"], "solver.modes: expected 'auto' or an integer >= 1, got 0"),
])
def test_bad_reduced_model_input(tmp_path, overrides, message):
    from conftest import run_cli

    args = [a for o in ["solver.method=modal", "mesh.cells=50", *overrides] for a in ("--set", o)]
    proc = run_cli("run", str(BAR), "-o", str(tmp_path / "out"), *args)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out").exists()


def test_second_run_reuses_modes_and_static_solves(tmp_path):
    """Cached by a hash of K, M, supports and load patterns: the same scene reuses them, the
    same history comes out, and a changed scene (another material) does not pick them up."""
    args = ["solver.method=modal", "solver.modes=8", "mesh.cells=40", "output.vtk=false"]
    first, h1 = run_case_file(BAR, tmp_path / "a", *args)
    second, h2 = run_case_file(BAR, tmp_path / "b", *args)
    other, _ = run_case_file(BAR, tmp_path / "c", *args, "material.E=2.0")
    assert first["reused_from_cache"] == []
    assert second["reused_from_cache"] == ["modes", "static solves"]
    assert other["reused_from_cache"] == []
    for name in h1.dtype.names:
        np.testing.assert_array_equal(h1[name], h2[name])


def test_modes_auto_picks_the_smallest_count_that_meets_the_tolerance(tmp_path):
    """`modes: auto`: the fewest modes whose neglected flexibility at the wall is within the
    tolerance - one mode fewer is not - when the flexibility is the binding criterion (coarse
    output); with the default output the cut-off frequency (half the output rate) decides."""
    # Output every 100 steps resolves 2.5 Hz: the flexibility decides.
    auto = ["solver.method=modal", "solver.modes=auto", "solver.tolerance=0.05", "output.vtk=false"]
    summary, _ = run_case_file(BAR, tmp_path / "auto", *auto, "output.every=100")
    n1 = summary["modes"]
    assert summary["neglected_flexibility"]["wall"] <= 0.05
    assert "neglected flexibility decided" in summary["modes_reason"]
    fewer, _ = run_case_file(BAR, tmp_path / "fewer", "solver.method=modal", f"solver.modes={n1 - 1}",
                             "output.vtk=false")
    assert fewer["neglected_flexibility"]["wall"] > 0.05
    # Output every 20 steps resolves 12.5 Hz: the bar's modes are k/2 Hz, so 26 modes (1 rigid).
    fine, _ = run_case_file(BAR, tmp_path / "fine", *auto)
    assert "cut-off frequency decided" in fine["modes_reason"]
    assert fine["modes"] == 26 and fine["cutoff_hz"] == pytest.approx(12.5, rel=0.01)


def test_truncation_error_does_not_shrink_with_the_time_step(tmp_path):
    """Plain truncation misses the contact compliance: halving dt twice leaves its error as it
    is (5.3 % on the force), while the statically corrected model stays within 0.3 %."""
    errors = {}
    for dt in (0.002, 0.0005):
        for static in (False, True):
            _, h = run_case_file(BAR, tmp_path / f"{dt}-{static}", "solver.method=modal", "solver.scheme=newmark",
                                 "solver.modes=10",
                                 f"solver.static_correction={str(static).lower()}", f"solver.dt={dt}",
                                 "output.vtk=false")
            errors[dt, static] = b2_checks(h, **B2A)["mean_force"]
    assert errors[0.002, False] > 0.04
    assert errors[0.0005, False] == pytest.approx(errors[0.002, False], rel=0.05)
    assert errors[0.002, True] < 0.005 and errors[0.0005, True] < 0.005


def test_modes_auto_reaches_twice_the_drive_frequency(tmp_path):
    """Clamped-free rod (c = L = 1): modes at (2k - 1)/4 Hz. The output (every 10 steps of 0.01 s)
    resolves 5 Hz, which 11 modes reach (5.25 Hz); driven at 3 Hz, auto keeps modes up to at
    least twice the drive, 6 Hz (13 modes: 6.25 Hz), and says that the load decided."""
    common = ["supports=[{nodes: right, fix: [x]}]", "initial.velocity=[0.0]", "contacts=[]", "mesh.cells=100",
              "solver.method=modal", "solver.modes=auto", "solver.tolerance=0.5", "solver.dt=0.01",
              "solver.t_end=4", "output.every=10", "output.vtk=false"]
    quiet, _ = run_case_file(BAR, tmp_path / "quiet", *common, "loads=[{nodes: left, force: [1.0]}]")
    assert quiet["modes"] == 11 and "output rate" in quiet["modes_reason"]
    driven, _ = run_case_file(BAR, tmp_path / "driven", *common, "loads=[{nodes: left, force: ['sin(2*pi*3*t)']}]")
    assert 6.0 <= driven["cutoff_hz"] < 8.0
    assert driven["modes"] >= 13 and "sin(2*pi*3*t)" in driven["modes_reason"]


def reduction_rows(tmp_path, *args, modes=(2, 5, 10)):
    """``fem-impact reduction cases/beam_stop.yaml --modes 2,5,10 ARGS``: rows by (modes, static)."""
    result = run_cli("reduction", str(CASES / "beam_stop.yaml"), "--modes", ",".join(map(str, modes)),
                     "-o", str(tmp_path), *args)
    assert result.returncode == 0, result.stderr
    with open(tmp_path / "reduction.csv") as f:
        rows = {(r["modes"], r["static_correction"]): r for r in csv.DictReader(f)}
    assert set(rows) == {("", ""), *((str(n), s) for n in modes for s in ("True", "False"))}
    for r in rows.values():                                              # every run timed, every column set
        assert float(r["wall_time_s"]) > 0 and r["displacement_error_band"] != "" and r["velocity_error_peak"] != ""
    assert "disp L2" in result.stdout and "vel peak" in result.stdout
    assert (tmp_path / "reduction.png").stat().st_size > 10_000     # the histories, drawn
    return rows


def column_of(rows, key, static):
    return [float(rows[(n, static)][key]) for n in ("2", "5", "10")]


def test_b3_reduction_table(tmp_path):
    """B3 (cases/beam_stop.yaml, docs/benchmarks.md B3): `fem-impact reduction` against the full model.

    The reference code's figures (5 modes + 1 static mode: 1.8 % on the tip displacement, 0.6 %
    on the tip velocity; 5 modes alone 7.1 %, 3.2 %) are errors of the histories' extreme values
    on a beam model; the full 2D model also rings above the kept band, so the peaks are those of
    the band-limited histories (measured at n1 = 5: 0.13 % and 0.05 % corrected, 0.53 % and 1.26 %
    plain). With the static correction the errors fall with n1 (relative L2 of the displacement
    4.5, 0.43, 0.03 %; in-band velocity 3.3, 0.74, 0.11 %) and beat plain truncation at every n1
    (8.0, 0.93, 0.33 %; 9.4, 3.6, 1.5 %)."""
    rows = reduction_rows(tmp_path / "b3", modes=(2, 5, 10, 20))
    peak_u, peak_v = (float(rows[("5", "True")][k]) for k in ("displacement_error_peak", "velocity_error_peak"))
    assert peak_u < 0.018 and peak_v < 0.006                             # docs/benchmarks.md B3: the bar at n1 = 5
    plain_u, plain_v = (float(rows[("5", "False")][k]) for k in ("displacement_error_peak", "velocity_error_peak"))
    assert plain_u < 0.071 and plain_v < 0.032 and plain_v > 3 * peak_v
    for key in ("displacement_error", "velocity_error_band", "impulse_error"):
        static, plain = column_of(rows, key, "True"), column_of(rows, key, "False")
        assert static[0] > static[1] > static[2], key                   # converges with n1
        assert all(s < p for s, p in zip(static, plain, strict=True)), key
    assert column_of(rows, "displacement_error", "True")[2] < 0.001
    assert float(rows[("20", "True")]["displacement_error"]) < 0.001


def test_b3_point_stop_truncation_alone_does_not_converge(tmp_path):
    """B3 with a rigid stop under one corner node: plain truncation misses the tip's local static
    compliance under the point force and stays near 18 % whatever n1 (measured 18.6, 17.9, 18.6 %
    relative L2 of the contact node's displacement); the corrected model converges (6.8, 2.2,
    0.93 %) and is at least 5 times closer from n1 = 5 on."""
    rows = reduction_rows(tmp_path / "point", "--set", "contacts.0.nodes=right_bottom", "--set",
                          "contacts.0.coupling=each", "--set", "contacts.0.stiffness=null",
                          "--set", "output.probes={tip: [1.0, 0.0]}")
    static, plain = column_of(rows, "displacement_error", "True"), column_of(rows, "displacement_error", "False")
    impulse = column_of(rows, "impulse_error", "True")
    assert static[0] > static[1] > static[2] and static[2] < 0.015
    assert impulse[0] > impulse[1] > impulse[2]
    assert min(plain) > 0.1 and max(plain) / min(plain) < 1.2          # truncation alone does not converge
    assert all(p > 5 * s for p, s in zip(plain[1:], static[1:], strict=True))
