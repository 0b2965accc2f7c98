"""The study commands: exact references, the method registry, running levels (resume, parallel
processes, failures), the coarse version of each `fem-impact study` command, bad input, and where
each method fails. Every method runs on the impacting bar: a test of one never skips.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from conftest import CASES, b1_exact_u0, run_cli
from fem_impact.config.case import CaseError, load_case
from fem_impact.references import B1, B2, BarMode, errors, from_case
from fem_impact.app.studies import convergence
from fem_impact.app.studies import methods as registry
from fem_impact.app.studies.levels import Level, StudyStopped, run_levels
from fem_impact.app.studies.pareto import pareto_front
from fem_impact.app.studies.stability import FORCE_OSCILLATION, chattering, classify, stability_study

BAR = CASES / "impacting_bar.yaml"
SIGNORINI = CASES / "signorini_bar.yaml"


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


# --- exact references --------------------------------------------------------------------------


def field_energy(ref, L, rho, E, A, t, n=4001):
    """Kinetic + strain energy of an exact field w(s, t), by finite differences in s and t."""
    s = np.linspace(0.0, L, n)
    dt = 1e-6
    w, w1, w0 = ref.w(s, t), ref.w(s, t + dt), ref.w(s, t - dt)
    v, strain = (w1 - w0) / (2 * dt), np.gradient(w, s)
    kinetic = 0.5 * rho * A * np.trapz(v**2, s)
    return kinetic + 0.5 * E * A * np.trapz(strain**2, s)


def test_b2_exact_field_keeps_its_energy_and_the_wall():
    """The three-plane solution min(v0 t, g0 + v0 s/c, 2 g0 + 2 v0 L/c - v0 t) is d'Alembert's: its
    energy is rho A L v0^2/2 at every time, the contact end stays on the wall for 2L/c, and it
    leaves at +v0 (here the steel bar, B2b: force 1270.8 N, impulse 0.48984 N s)."""
    ref = from_case(load_case(CASES / "impacting_bar_steel.yaml"))
    assert isinstance(ref, B2) and ref.F == pytest.approx(1270.8, rel=1e-4)
    assert ref.impulse_total(1.5e-3) == pytest.approx(0.48984, rel=1e-4)
    assert ref.t0 == pytest.approx(5.0e-4) and ref.t0 + ref.duration == pytest.approx(8.854e-4, rel=1e-4)
    for t in (2e-4, 6e-4, 7.5e-4, 8.5e-4, 1.2e-3):   # before, during (wave in, wave back) and after contact
        e = field_energy(ref, 1.0, 7800.0, 210e9, 3.14e-4, t)
        assert e == pytest.approx(ref.energy_scale, rel=2e-3), t
    t = np.linspace(0, 1.5e-3, 301)
    inside = (t >= ref.t0) & (t <= ref.t0 + ref.duration)
    np.testing.assert_allclose(ref.w(0.0, t)[inside], 5e-5)
    late = t > ref.t0 + ref.duration
    np.testing.assert_allclose(np.gradient(ref.displacement("right", t[late]), t[late]), 0.1)


def test_b1_exact_field_matches_the_table_and_keeps_its_energy():
    """B1 by d'Alembert: u(0, t) as in the table of docs/benchmarks.md B1, u(L, t) = 0 (clamp), period 3, energy
    1/8 at every time, the contact force 1/2 on [1, 2] mod 3."""
    ref = from_case(load_case(SIGNORINI))
    assert isinstance(ref, B1)
    t = np.linspace(0.0, 12.0, 2401)
    np.testing.assert_allclose(ref.displacement("left", t), b1_exact_u0(t), atol=1e-14)
    np.testing.assert_allclose(ref.w(1.0, t), 0.0, atol=1e-14)
    np.testing.assert_allclose(ref.w(0.3, t + 3.0), ref.w(0.3, t), atol=1e-14)
    for tt in (0.3, 0.8, 1.2, 1.7, 2.4, 2.9, 4.5):
        assert field_energy(ref, 1.0, 1.0, 1.0, 1.0, tt) == pytest.approx(1 / 8, rel=2e-3), tt
    assert ref.force(np.array([0.5, 1.5, 2.5, 4.5])).tolist() == [0.0, 0.5, 0.0, 0.5]
    assert ref.impulse_total(12.0) == pytest.approx(4 * 0.5)


def test_exact_history_has_no_error():
    """The error measures of the exact solution sampled as a history are zero (B2a, dt = 0.01)."""
    ref = from_case(load_case(BAR))
    t = np.linspace(0.0, 4.0, 401)
    overlap = np.clip(np.minimum(t, ref.t0 + ref.duration) - np.maximum(t - 0.01, ref.t0), 0.0, None)
    energy = np.full_like(t, 0.5)
    h = {"t": t, "left.ux": ref.displacement("left", t), "right.ux": ref.displacement("right", t),
         "wall.force": ref.force(t), "wall.impulse": ref.F * overlap, "kinetic": energy, "strain": 0 * t,
         "external_work": 0 * t}
    for name, value in errors(h, ref).items():
        assert value == pytest.approx(0.0, abs=1e-12), name


def test_free_vibration_reference_reads_the_mode_from_the_case():
    ref = from_case(load_case(CASES / "free_vibration.yaml"))
    assert isinstance(ref, BarMode) and ref.mode == 1 and ref.omega == pytest.approx(math.pi)
    assert ref.a == pytest.approx(0.01) and ref.energy_scale == pytest.approx(math.pi**2 * 1e-4 / 4)
    clamped = from_case(load_case(CASES / "free_vibration.yaml", [
        "supports=[{nodes: right, fix: [x]}]", "initial.displacement=['0.02*cos(3*pi*x/2)']"]))
    assert clamped.mode == 2 and clamped.omega == pytest.approx(1.5 * math.pi)


@pytest.mark.parametrize("case, overrides, message", [
    (BAR, ["reference=b1"], "reference: b1: needs one support holding x at the other end (right)"),
    (SIGNORINI, ["reference=b2"], "reference: b2: is a free bar: remove 'supports'"),
    (BAR, ["reference=bar_mode"], "reference: bar_mode: is free vibration without contact"),
    (BAR, ["initial.velocity=[1.0]"], "toward the wall"),
    (BAR, ["mesh.dim=2", "material.nu=0.3"], "behaves as the rod only with nu = 0"),
    (SIGNORINI, ["initial.displacement=['(1 - x)**2/2']"], "needs the initial displacement a (1 - s/L)"),
    (CASES / "two_bars.yaml", ["reference=b2"], "needs the built-in bar"),
])
def test_a_reference_refuses_a_case_it_does_not_fit(case, overrides, message):
    with pytest.raises(CaseError) as err:
        from_case(load_case(case, overrides))
    assert message in str(err.value)
    assert err.value.key == "reference"


def test_reference_key_is_validated_and_resolved(tmp_path):
    with pytest.raises(CaseError) as err:
        load_case(BAR, ["reference=b3"])
    assert ("reference: unknown reference 'b3'; known references: b1 (clamped bar released against an "
            "obstacle), b2 (free bar hitting a rigid wall), bar_mode") in str(err.value)
    case = load_case(BAR)
    path = case.write_resolved(tmp_path / "case.resolved.yaml")
    assert "reference: b2\n" in path.read_text() and load_case(path).reference == "b2"
    assert load_case(CASES / "two_bars.yaml").reference is None
    # The file's line of the key is named when the value is wrong.
    bad = tmp_path / "bad.yaml"
    bad.write_text(BAR.read_text().replace("reference: b2 ", "reference: b9 "))
    with pytest.raises(CaseError) as err:
        load_case(bad)
    assert err.value.line == 5


# --- the method registry ---------------------------------------------------------------------------


def test_every_method_runs_on_the_impacting_bar():
    """Every registered method takes the frictionless bar (the tests of each method below rely on it:
    a method that stops accepting it fails here, not as a skip)."""
    for method in registry.METHODS.values():
        assert registry.availability(method, load_case(BAR)) is None, method.name
        assert registry.available(method.name, load_case(BAR)), method.name
        assert method.description and method.stability and method.knob in ("mesh", "modes")
    assert registry.METHODS["central-difference"].max_courant == 1.0
    with pytest.raises(registry.UnknownMethod, match="unknown method 'verlet'"):
        registry.parse_methods("trapezoidal,verlet")
    assert [m.name for m in registry.parse_methods(None)] == list(registry.METHODS)


def test_friction_case_methods_refuse_with_the_reason_or_run_when_a_given_change_mends_them():
    """On a case with friction the methods whose contact step is an LCP refuse with the reason; the
    modal Moreau-Jean runs (friction through the static correction, docs/theory.md s. 8.9), also when the
    study is given ``solver.static_correction=false`` (the method's changes and the given ones in one
    change); the truncated modal method (Newmark's step, an LCP) refuses."""
    case = load_case(CASES / "sliding_block.yaml")
    assert registry.availability("moreau-jean", case) is None
    why = registry.availability("trapezoidal", case)
    assert why.startswith("does not run on this case (contacts[0].friction: ") and "moreau_jean" in why
    assert registry.availability("modal-moreau-jean", case) is None
    assert registry.apply("modal-moreau-jean", case).solver.static_correction is True
    given = ["solver.static_correction=false", "solver.modes=40"]
    assert registry.availability("modal-moreau-jean", case, given) is None
    mended = registry.apply("modal-moreau-jean", case, given)
    assert (mended.solver.method, mended.solver.static_correction, mended.solver.modes) == ("modal", False, 40)
    assert registry.changes_for("modal-moreau-jean", case, {"solver.static_correction": False})[
        "solver.static_correction"] is False
    assert registry.availability("modal-truncated", case, given).startswith("does not run on this case")


def test_a_method_is_applied_as_changes_and_the_given_changes_win():
    """A method is a mapping of changes; a study's given changes (the command line's --set) come after
    them in the same change, so they win and may set the method's own keys (docs/studies.md: `--set
    solver.modes=40` changes the modal methods' n1), which the file's newmark case alone refuses."""
    case = registry.apply("modal-static", load_case(BAR))
    assert (case.solver.method, case.solver.scheme, case.solver.modes) == ("modal", "newmark", 20)
    with pytest.raises(CaseError, match="does not use 'modes'"):
        load_case(BAR, ["solver.modes=40"])
    assert registry.apply("modal-static", load_case(BAR), ["solver.modes=40"]).solver.modes == 40
    # a solver key goes to the methods that take it; any other bad change is refused, named as given
    assert registry.availability("central-difference", load_case(BAR), ["solver.beta=0.1"]) is None
    why = registry.availability("central-difference", load_case(BAR), ["contacts.0.restitution=2"])
    assert why.startswith("does not run on this case (contacts[0].restitution: ") \
        and "(from --set contacts.0.restitution=2)" in why
    with pytest.raises(CaseError, match="does not use 'modes'"):   # a convergence study's one method: refused
        convergence.plan(load_case(BAR), [("solver.dt", ["0.004", "0.002"])], method="trapezoidal",
                         changes=["solver.modes=40"])
    p = convergence.plan(load_case(BAR), [("solver.dt", ["0.004", "0.002"])], method="modal-static",
                         changes=["solver.modes=40", "solver.static_correction=false"])
    for lv in p["levels"]:
        level = load_case(BAR).with_changes(lv.changes)
        assert (level.solver.method, level.solver.modes, level.solver.static_correction) == ("modal", 40, False)


# --- levels: resume, parallel processes, failures -------------------------------------------------


def coarse(*extra):
    """A level's changes: a coarse, short B2a, and ``extra`` mappings on top."""
    changes = {"output.vtk": False, "mesh.cells": 20, "solver.dt": 0.025, "solver.t_end": 2.5}
    for more in extra:
        changes.update(more)
    return changes


def test_levels_resume_and_rerun_what_changed(tmp_path):
    levels = [Level("a", coarse()), Level("b", coarse({"contacts.0.restitution": 1.0}))]
    first = run_levels(load_case(BAR), levels, tmp_path, quiet=True)
    assert [o.status for o in first] == ["ok", "ok"] and not any(o.resumed for o in first)
    record = json.loads((tmp_path / "levels" / "a" / "level.json").read_text())
    assert record["changes"] == coarse() and record["status"] == "ok"
    stamp = (tmp_path / "levels" / "a" / "history.csv").stat().st_mtime_ns
    levels[1] = Level("b", coarse({"contacts.0.restitution": 0.5}))   # changed: run again
    second = run_levels(load_case(BAR), levels, tmp_path, quiet=True)
    assert [o.resumed for o in second] == [True, False]
    assert (tmp_path / "levels" / "a" / "history.csv").stat().st_mtime_ns == stamp
    assert second[0].summary == first[0].summary


def test_parallel_levels_give_the_same_history(tmp_path):
    levels = [Level("a", coarse()), Level("b", coarse({"mesh.cells": 40, "solver.dt": 0.0125}))]
    serial = run_levels(load_case(BAR), levels, tmp_path / "serial", quiet=True)
    parallel = run_levels(load_case(BAR), levels, tmp_path / "parallel", jobs=2, quiet=True)
    for s, p in zip(serial, parallel, strict=True):
        assert p.ok and not p.resumed
        hs, hp = s.history(), p.history()
        for name in hs:
            if name != "energy_error":
                np.testing.assert_array_equal(hs[name], hp[name], err_msg=name)


# Newmark with gamma = 1/2 is stable for w dt <= 1 / sqrt(gamma/2 - beta) (beta < gamma/2); the
# 1D bar with consistent mass has w_max = 2 sqrt(3) c/h, so with beta = 0.1 the limit is the Courant
# number 1 / (2 sqrt(3) sqrt(0.15)) = 0.745.
UNSTABLE = ("solver.beta=0.1",)
UNSTABLE_CHANGES = {"solver.beta": 0.1}


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_level_that_blows_up_stops_the_study_or_is_recorded(tmp_path, jobs):
    # 20 cells, Courant 2 (dt = 0.1) for 400 steps: the unstable modes overflow within the run.
    levels = [Level("stable", coarse(UNSTABLE_CHANGES, {"solver.dt": 0.025, "solver.t_end": 40})),
              Level("unstable", coarse(UNSTABLE_CHANGES, {"solver.dt": 0.1, "solver.t_end": 40}))]
    with pytest.raises(StudyStopped) as stop:
        run_levels(load_case(BAR), levels, tmp_path, jobs=jobs, quiet=True)
    assert stop.value.outcome.level.name == "unstable"
    reason = stop.value.outcome.reason
    assert "finite" in reason or "blew up" in reason
    record = json.loads((tmp_path / "levels" / "unstable" / "level.json").read_text())
    assert record["status"] == "failed" and record["reason"] == reason
    assert not (tmp_path / "levels" / "unstable" / "history.csv").exists()   # no NaN fields written
    # A rerun keeps the failure (and the stable level, unless the failure interrupted it: -j 2).
    outcomes = run_levels(load_case(BAR), levels, tmp_path, jobs=jobs, allow_failure=True, quiet=True)
    assert [o.status for o in outcomes] == ["ok", "failed"] and outcomes[1].resumed
    assert outcomes[0].resumed or jobs > 1


# Central difference at Courant 2 on the coarse bar (20 cells, dt = 0.1): blows up within 5 steps.
ABOVE_COURANT = {"solver.method": "central_difference", "solver.mass": "lumped", "solver.dt": 0.1}
# 4e8 steps: the run refuses it when it starts (fem_impact.app.limits), as bad input.
TOO_LONG = {"solver.t_end": 1e7}


@pytest.mark.parametrize("jobs", [1, 2])
def test_each_level_reports_a_structured_status(tmp_path, jobs):
    """A level whose run fails is `failed` with the run's message and error type; a level the run refuses
    is `skipped` with the CaseError's message; the same in this process (-j 1) and from the worker
    processes (-j 2), which report a JSON status (never read from their stderr). Both run the level's case
    from its data (Case.resolved()), so the reasons do not depend on -j."""
    levels = [Level("ok", coarse()), Level("above-courant", coarse(ABOVE_COURANT)),
              Level("too-long", coarse(TOO_LONG))]
    outcomes = run_levels(load_case(BAR), levels, tmp_path, jobs=jobs, allow_failure=True, quiet=True)
    ok, failed, skipped = outcomes
    assert ok.status == "ok" and ok.summary["steps"] == 100 and ok.error is None
    assert failed.status == "failed" and failed.error == "SimulationError"
    assert failed.reason.startswith("blew up at t = ") and failed.summary is None
    assert skipped.status == "skipped" and skipped.error == "CaseError"
    assert skipped.reason == ("solver.dt: the run would take 4e+08 steps (t_end / dt = 1e+07 / 0.025), more than "
                              "the limit 1e+08; pass --force to run it anyway")   # (the same whatever -j)
    for o in outcomes:
        record = json.loads((tmp_path / "levels" / o.level.name / "level.json").read_text())
        assert (record["status"], record["reason"], record["error"]) == (o.status, o.reason, o.error)
        assert o.case.solver.dt == (0.1 if o is failed else 0.025)   # the level's case, for the study's tables
    assert sorted(p.name for p in (tmp_path / "levels" / "above-courant").iterdir()) == ["level.json"]
    assert not list(tmp_path.glob(".cache-*"))   # the private cache and the workers' files are gone


def test_a_worker_that_dies_without_a_status_is_a_failed_level(tmp_path):
    """No status file (killed, or dead before it could write one): failed, whatever its stderr says."""
    from fem_impact.app.studies.levels import _from_child

    (tmp_path / "x.log").write_text("fem-impact: the run failed: looks like a reason\n")
    outcome = _from_child(Level("x", {}), tmp_path / "x", None, -9, tmp_path / "x.status.json", tmp_path / "x.log")
    assert (outcome.status, outcome.reason) == ("failed", "the run killed by signal 9 without reporting its status")


def test_no_study_sweep_or_reduction_starts_a_fem_impact_run_process(tmp_path, monkeypatch):
    """-j 2 starts the worker module (the case as data in, a JSON status out); the sweep and the
    reduction table run fem_impact.run in this process."""
    from fem_impact.app.studies import reduction_table
    from fem_impact.app.sweep import run_sweep

    started = []
    popen = subprocess.Popen

    def recording(args, *rest, **options):
        started.append([str(a) for a in args])
        return popen(args, *rest, **options)

    monkeypatch.setattr(subprocess, "Popen", recording)
    case = load_case(BAR).with_changes(coarse())
    run_levels(case, [Level("a", {}), Level("b", {"mesh.cells": 40})], tmp_path / "study", jobs=2, quiet=True)
    run_sweep(case, "contacts.0.restitution=0,1", outdir=tmp_path / "sweep", progress=False, report=None)
    reduction_table(case, modes=(2,), outdir=tmp_path / "reduction")
    workers = [a for a in started if a[1:3] == ["-m", "fem_impact.app.studies.worker"]]
    assert len(workers) == 2 and all(a[0] == sys.executable for a in workers)
    assert not [a for a in started if "fem_impact" in a or "run" in a], started
    assert (tmp_path / "sweep" / "sweep.csv").is_file() and (tmp_path / "reduction" / "reduction.csv").is_file()


def test_an_interrupted_parallel_study_stops_its_workers_and_leaves_no_staging_folder(tmp_path):
    """Ctrl-C (SIGINT to the study alone): the study signals its workers, which remove their staging
    folders; 130, one line; the private cache is removed and no level is recorded."""
    out = tmp_path / "study"
    proc = subprocess.Popen([sys.executable, "-m", "fem_impact", "study", "convergence", str(BAR), "-o", str(out),
                             "-j", "2", "--vary", "solver.t_end=200,201", *sets("mesh.cells=50", "solver.dt=0.0005",
                                                                                 "output.every=100000")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while len(stages := list((out / "levels").glob(".*.partial-*")) if (out / "levels").exists() else []) < 2:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the levels did not start"
        time.sleep(0.1)
    workers = [int(p.name.rsplit("-", 1)[1]) for p in stages]
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1].startswith("fem-impact: interrupted by SIGINT"), stderr
    left = [p.relative_to(tmp_path) for p in tmp_path.rglob("*")]
    assert not [p for p in left if ".partial-" in p.name or p.name.startswith(".cache-") or p.name == "level.json"]
    for pid in workers:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


# --- the commands, coarse ---------------------------------------------------------------------------


def sets(*options):
    return [a for o in options for a in ("--set", o)]


def test_convergence_command(tmp_path):
    """Default folder results/<case>-convergence/, the table, the files, and a resumed rerun."""
    args = ["study", "convergence", str(BAR), "--vary", "mesh.cells=20,40,80", *sets("solver.t_end=2.5")]
    proc = run_cli(*args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "results" / "impacting_bar-convergence"
    assert "fitted order" in proc.stdout and "exact b2" in proc.stdout
    assert proc.stderr.count("ok, ") == 3 and "left)" in proc.stderr
    rows = read_csv(out / "convergence.csv")
    assert [r["mesh.cells"] for r in rows] == ["20", "40", "80"]
    assert all(float(r["courant"]) == pytest.approx(0.5) for r in rows)
    assert float(rows[0]["err_displacement"]) > float(rows[2]["err_displacement"]) > 0
    study = json.loads((out / "study.json").read_text())
    assert study["orders"]["err_energy"] == pytest.approx(1.0, abs=0.15)
    assert study["overrides"] == ["solver.t_end=2.5"] and study["case"] == str(BAR.resolve())
    assert (out / "convergence.png").stat().st_size > 10_000
    again = run_cli(*args, cwd=tmp_path)
    assert again.returncode == 0 and again.stderr.count("kept from an earlier run (ok)") == 3
    assert read_csv(out / "convergence.csv") == rows


def test_pareto_command(tmp_path):
    """Two rungs per method on a coarse B2a; the columns of the issue; a front; every method given runs."""
    out = tmp_path / "pareto"
    proc = run_cli("study", "pareto", str(BAR), "--methods", "trapezoidal,modal-static,position-only",
                   "--levels", "2", "-o", str(out), *sets("mesh.cells=80", "solver.t_end=2.5"))
    assert proc.returncode == 0, proc.stderr
    rows = read_csv(out / "pareto.csv")
    for column in ("method", "resolution", "unknowns", "steps", "modes", "setup_time_s", "loop_time_s",
                   "wall_time_s", "err_displacement", "err_impulse", "err_force", "err_energy", "force_oscillation"):
        assert column in rows[0], column
    got = {(r["method"], r["resolution"]) for r in rows}
    assert {("trapezoidal", "10"), ("trapezoidal", "20"), ("modal-static", "5"), ("modal-static", "10")} <= got
    assert ("position-only", "10") in got and "position-only skipped" not in proc.stderr
    assert "Pareto front, displacement" in proc.stdout
    assert (out / "pareto.png").stat().st_size > 20_000


def test_pareto_front():
    rows = [{"status": "ok", "wall_time_s": t, "e": e} for t, e in [(1, 0.5), (2, 0.6), (3, 0.1), (0.5, 0.9)]]
    rows.append({"status": "failed", "wall_time_s": 0.1, "e": math.nan})
    assert pareto_front(rows, "e", "wall_time_s") == [3, 0, 2]


def test_stability_command(tmp_path):
    """A coarse sweep of the trapezoidal rule made conditionally stable (beta = 0.1): the map and CSV."""
    out = tmp_path / "stability"
    proc = run_cli("study", "stability", str(BAR), "--methods", "trapezoidal", "--courant", "0.5,2",
                   "--restitution", "0,1", "--length", "1,2", "-o", str(out),
                   *sets("mesh.cells=20", "solver.t_end=2.5", *UNSTABLE))
    assert proc.returncode == 0, proc.stderr
    rows = read_csv(out / "stability.csv")
    by = {(r["sweep"], float(r["value"])): r for r in rows}
    assert set(by) == {("courant", 0.5), ("courant", 2.0), ("restitution", 0.0), ("restitution", 1.0),
                       ("length", 1.0), ("length", 2.0)}
    assert by["courant", 0.5]["outcome"] == "accurate"
    assert by["courant", 2.0]["outcome"] == "failed" and by["courant", 2.0]["reason"]
    assert (out / "stability.png").stat().st_size > 10_000
    assert "failed:" in proc.stdout


BAD = {
    "unknown-key": (["convergence", "--vary", "mesh.cellz=10,20"],
                    "mesh.cellz: unknown key 'cellz'; did you mean 'cells'?"),
    "non-numeric": (["convergence", "--vary", "mesh.cells=10,abc"], "--vary mesh.cells: level 'abc' is not a number"),
    "one-level": (["convergence", "--vary", "mesh.cells=10"], "give at least two levels"),
    "no-vary": (["convergence"], "--vary: give at least one"),
    "method": (["convergence", "--vary", "mesh.cells=10,20", "--method", "verlet"], "unknown method 'verlet'"),
    "methods": (["pareto", "--methods", "trapezoidal,verlet"], "unknown method 'verlet'"),
    "courant": (["convergence", "--vary", "mesh.cells=10,20", "--courant", "abc"], "--courant abc: expected a number"),
    "jobs": (["pareto", "-j", "0"], "-j 0: give at least 1"),
    "conflict": (["convergence", "--vary", "solver.dt=0.1,0.05", "--courant", "1"], "cannot be combined"),
    "restitution": (["stability", "--restitution", "0,2"], "--restitution: every value must be in [0, 1]"),
    "reference": (["convergence", "--vary", "mesh.cells=10,20", "--set", "reference=b1"],
                  "reference: b1: needs one support"),
    "levels": (["pareto", "--levels", "1"], "--levels 1: give at least 2 rungs"),
}


@pytest.fixture(scope="module")
def bad_outcomes(tmp_path_factory):
    root = tmp_path_factory.mktemp("bad-studies")

    def call(item):
        name, (args, _) = item
        kind, rest = args[0], args[1:]
        return name, run_cli("study", kind, str(BAR), "-o", str(root / name), *rest)

    with ThreadPoolExecutor(4) as pool:
        return root, dict(pool.map(call, BAD.items()))


@pytest.mark.parametrize("name", BAD)
def test_bad_study_input(bad_outcomes, name):
    root, outcomes = bad_outcomes
    proc = outcomes[name]
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fem-impact: error: ") and BAD[name][1] in lines[0], lines
    assert not (root / name).exists()


# --- where each method fails ("Done when" 2) -------------------------------------------------------


def test_newmark_beyond_its_stability_limit_is_detected_unconditional_schemes_are_not(tmp_path):
    """beta = 0.1, gamma = 1/2: stable up to Courant 0.745 (derivation at UNSTABLE): 0.7 runs, 0.8 and
    above fail (energy growth, or the integrator's blow-up error). The trapezoidal rule and the damped
    Newmark (2 beta >= gamma >= 1/2) never fail up to Courant 4."""
    result = stability_study(load_case(BAR, ["mesh.cells=50", *UNSTABLE]), methods="trapezoidal",
                             courants=[0.7, 0.8, 2.0], restitutions=[], lengths=[1], outdir=tmp_path / "conditional",
                             quiet=True)
    outcome = {r["value"]: r["outcome"] for r in result["rows"] if r["sweep"] == "courant"}
    assert outcome[0.7] != "failed" and outcome[0.8] == "failed" and outcome[2.0] == "failed"
    result = stability_study(load_case(BAR, ["mesh.cells=50"]), methods="trapezoidal,damped-newmark",
                             courants=[0.1, 1.0, 4.0], restitutions=[], lengths=[1], outdir=tmp_path / "unconditional",
                             quiet=True)
    assert all(r["outcome"] != "failed" and r["energy_growth"] < 1e-9 for r in result["rows"])


def test_central_difference_blows_up_above_the_cfl_limit(tmp_path):
    """Explicit central difference with a lumped mass: stable for c dt / h <= 1 (1D); above, the
    highest mode grows every step and the run stops with a blow-up that the study records."""
    result = stability_study(load_case(BAR, ["mesh.cells=100"]), methods="central-difference",
                             courants=[0.5, 0.9, 2.0], restitutions=[], lengths=[1], outdir=tmp_path, quiet=True)
    outcome = {r["value"]: r for r in result["rows"] if r["sweep"] == "courant"}
    assert outcome[0.5]["outcome"] != "failed" and outcome[0.9]["outcome"] != "failed"
    assert outcome[2.0]["outcome"] == "failed" and outcome[2.0]["reason"]


@pytest.mark.parametrize("case", [BAR, SIGNORINI], ids=["b2", "b1"])
@pytest.mark.parametrize("method, oscillates", [
    ("position-only", True),
    ("trapezoidal", False),
    ("mass-redistribution", False),
])
def test_position_level_multipliers_alone_make_the_contact_force_oscillate(tmp_path, case, method, oscillates):
    """The contact force's RMS deviation from the exact force over the contact phases, relative to
    it (fem_impact.references.errors): with Carnot's correction 0.096 (B2a) and 0.18 (B1), with mass
    redistribution 0.10 and 0.18, the ringing of the discrete bar at the ends of a contact;
    position-level multipliers alone make the force jump between 0 and about 3 times its value
    (measured 2.92 on B2a, 2.82 on B1). Threshold FORCE_OSCILLATION = 0.5."""
    result = stability_study(load_case(case), methods=method, courants=[0.5], restitutions=[], lengths=[1],
                             outdir=tmp_path, quiet=True)
    (row,) = [r for r in result["rows"] if r["sweep"] == "courant"]
    if oscillates:
        assert row["force_oscillation"] > FORCE_OSCILLATION and row["outcome"] != "accurate"
    else:
        assert row["force_oscillation"] < FORCE_OSCILLATION
    if method == "trapezoidal":   # (measured: every error below 5 %)
        assert row["outcome"] == "accurate"


def test_chattering_and_classification():
    n = 200
    closed = np.zeros(n, dtype=bool)
    closed[100::2] = True            # switching every step to the end
    h = {"c.force": closed * 1.0, "c.impulse": np.zeros(n)}
    assert chattering(h, ["c"]) == (True, 100)   # a switch at every step from 100 to 199
    closed[180:] = True              # settles: no longer chattering at the end
    h["c.force"] = closed * 1.0
    to_end, most = chattering(h, ["c"])
    assert not to_end and most >= 70
    base = dict.fromkeys(("err_displacement", "err_impulse", "err_force", "err_energy", "force_oscillation"), 0.01)
    base.update(energy_growth=0.0, penetration=0.0, chatter_to_end=False, chatter_switches=0)
    assert classify("ok", "", base, 0.05)[0] == "accurate"
    assert classify("ok", "", {**base, "err_force": 0.2}, 0.05)[:2] == ("inaccurate",
                                                                          "contact force error 0.2 (> 0.05)")
    assert classify("ok", "", {**base, "force_oscillation": 0.9}, 0.05)[0] == "inaccurate"
    assert classify("ok", "", {**base, "energy_growth": 0.5}, 0.05)[0] == "failed"
    assert classify("ok", "", {**base, "penetration": 0.5}, 0.05)[0] == "failed"
    assert classify("ok", "", {**base, "chatter_to_end": True}, 0.05)[0] == "failed"
    assert classify("failed", "blew up: energy 1e9 exceeds 10", base, 0.05) == (
        "failed", "blew up: energy 1e9 exceeds 10", "blow-up")
    assert classify("skipped", "x", base, 0.05)[0] == "skipped"


def test_reduction_command_still_works(tmp_path):
    """`fem-impact reduction` lives in fem_impact/app/studies/reduction.py, importable as before."""
    from fem_impact.app.studies import format_reduction, reduction_table  # noqa: F401  (still importable)

    proc = run_cli("reduction", str(BAR), "--modes", "5", "-o", str(tmp_path / "red"),
                   *sets("mesh.cells=50", "solver.dt=0.01", "solver.t_end=2.5"))
    assert proc.returncode == 0, proc.stderr
    assert re.search(r"modal\s+5\s+yes", proc.stdout)
    rows = read_csv(tmp_path / "red" / "reduction.csv")
    assert [r["model"] for r in rows] == ["full", "modal", "modal"]


def test_a_given_solver_key_goes_to_the_methods_that_take_it():
    """``--set solver.modes=40`` in a study with many methods sets the modal methods' n1 and leaves the others as
    they are (their schema would refuse the key); any other key goes to every method."""
    case = load_case(CASES / "impacting_bar.yaml")
    given = {"solver.modes": 40, "mesh.cells": 100}
    modal = registry.changes_for("modal-static", case, given)
    assert (modal["solver.modes"], modal["mesh.cells"]) == (40, 100)
    full = registry.changes_for("trapezoidal", case, given)
    assert "solver.modes" not in full and full["mesh.cells"] == 100
    assert registry.apply("trapezoidal", case, ["solver.modes=40"]).solver.method == "newmark"
    assert registry.apply("modal-static", case, ["solver.modes=40"]).solver.modes == 40
    assert registry.availability("central-difference", case, given) is None


def test_a_stability_study_takes_a_list_valued_change(tmp_path):
    """``--set "loads=[{body: all, ...}]"`` (as the plate's map in docs/verification.md): a level's changes hold a list."""
    from fem_impact.app.studies.stability import stability_study

    result = stability_study(load_case(BAR), methods="moreau-jean", courants=[0.5], restitutions=[], lengths=[1.0],
                             changes=["mesh.cells=10", "solver.t_end=0.5", "reference=null",
                                      "loads=[{body: all, acceleration: [-0.5]}]"],
                             outdir=tmp_path / "s", quiet=True)
    assert [row["outcome"] for row in result["rows"]] and all(r["method"] == "moreau-jean" for r in result["rows"])


def test_a_pareto_ladder_runs_each_mesh_once():
    """A coarse case (8 cells): the lowest rungs all clamp to 2 cells, which runs once."""
    from fem_impact.app.studies.pareto import ladder

    case = load_case(CASES / "sliding_block.yaml")
    levels, _ = ladder(registry.get("moreau-jean"), case, {}, None, 5)
    assert [level.info["resolution"] for level in levels] == [2, 4, 8, 16]
