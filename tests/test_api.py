"""The Python API (issue 12): cases from files and dicts, runs that write nothing, one error hierarchy.

B2a (docs/benchmarks.md B2) built from a dict and run in memory gives B2's exact answers; bad input raises
CaseError naming the key; a run into a folder writes exactly what the command writes.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_bar_benchmarks import assert_b2, assert_energy

import fem_impact
from conftest import CASES, run_cli
from fem_impact import Case, CaseError, FemImpactError, SimulationError

# B2a: L = E = rho = A = v0 = 1, g0 = 0.1, t_end = 4; 250 cells at Courant 0.5.
B2A = {
    "name": "b2a",
    "mesh": {"shape": "bar", "dim": 1, "length": 1.0, "cells": 250},
    "material": {"E": 1.0, "rho": 1.0, "area": 1.0},
    "initial": {"velocity": [-1.0]},
    "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0], "gap": 0.1}],
    "solver": {"dt": 0.002, "t_end": 4.0},
    "output": {"probes": {"left": [0.0], "right": [1.0]}},
}


def files_under(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def test_b2a_from_a_dict_runs_in_memory_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = fem_impact.run(Case.from_dict(B2A))
    assert result.outdir is None and result.summary["outdir"] is None
    assert files_under(tmp_path) == set(), "a run with outdir=None wrote files"
    h = result.history
    assert len(h["t"]) == 2001 and isinstance(h["wall.force"], np.ndarray)
    assert_b2(h)   # contact start, duration, force, impulse, rebound, end displacement
    assert_energy(result.summary, h)
    assert result.summary["method"] == "moreau_jean" and result.summary["max_penetration"] < 1e-12


def test_a_negative_modulus_is_a_case_error_that_names_e():
    data = {**B2A, "material": {"E": -1, "rho": 1.0}}
    with pytest.raises(CaseError) as info:
        Case.from_dict(data)
    err = info.value
    assert (err.key, err.file, err.line) == ("material.E", None, None)
    assert str(err) == "material.E: must be > 0, got -1"
    assert isinstance(err, FemImpactError) and issubclass(SimulationError, FemImpactError)
    assert B2A["material"] == {"E": 1.0, "rho": 1.0, "area": 1.0}, "from_dict changed its input"


def test_paths_in_a_dict_start_at_base_dir(tmp_path):
    data = {**B2A, "mesh": {"file": "two_bars.msh"}}
    with pytest.raises(CaseError, match="mesh file not found"):
        Case.from_dict(data, base_dir=tmp_path)
    case = Case.from_dict(data, base_dir=CASES.parent / "meshes")
    assert case.mesh.file == (CASES.parent / "meshes" / "two_bars.msh").resolve()


def test_with_changes_gives_a_validated_copy():
    case = fem_impact.load_case(CASES / "impacting_bar.yaml")
    finer = case.with_changes({"mesh.cells": 500, "solver.dt": 0.001, "contacts.0.restitution": 0.5})
    assert (finer.mesh.cells, finer.solver.dt, finer.contacts[0].restitution) == (500, 0.001, 0.5)
    assert (case.mesh.cells, case.solver.dt, case.contacts[0].restitution) == (250, 0.002, 0.0)
    with pytest.raises(CaseError) as info:
        case.with_changes({"contacts.0.restitution": 2})
    err = info.value
    assert (err.key, err.line) == ("contacts[0].restitution", None)
    assert err.message == "must be in [0, 1], got 2 (from the change contacts.0.restitution=2)"


def test_a_run_into_a_folder_writes_what_the_command_writes(tmp_path):
    small = ["mesh.cells=40", "solver.dt=0.0125", "solver.t_end=0.5", "output.every=10"]
    case = fem_impact.load_case(CASES / "impacting_bar.yaml", small)
    result = fem_impact.run(case, tmp_path / "api")
    assert result.outdir == (tmp_path / "api").resolve()
    command = run_cli("run", str(CASES / "impacting_bar.yaml"), "-o", str(tmp_path / "cli"), "-q",
                      *(a for s in small for a in ("--set", s)))
    assert command.returncode == 0, command.stderr
    assert files_under(tmp_path / "api") == files_under(tmp_path / "cli")
    api, cli = (json.loads((tmp_path / n / "summary.json").read_text()) for n in ("api", "cli"))
    timings = {k for k in api if k.endswith("_time_s")}
    assert {k: v for k, v in api.items() if k not in timings} == {k: v for k, v in cli.items() if k not in timings}
    assert (tmp_path / "api" / "history.csv").read_text() == (tmp_path / "cli" / "history.csv").read_text()
    from fem_impact.app.plots import history_columns

    on_disk = history_columns(tmp_path / "api")
    assert set(result.history) == set(on_disk)
    for name, column in on_disk.items():
        np.testing.assert_array_equal(result.history[name], column)


def test_a_run_that_cannot_go_on_raises_a_simulation_error(tmp_path, monkeypatch):
    """The paper's scheme on issue 10's reproduction creates energy: with stop_on_energy_gain it stops."""
    monkeypatch.chdir(tmp_path)
    case = fem_impact.load_case(CASES / "beam_stop.yaml", [
        "contacts.0.stiffness=null", "contacts.0.coupling=each", "output.vtk=false",
        "solver.dt=2e-3", "solver.t_end=2", "solver.method=newmark"])
    with pytest.raises(SimulationError) as info:
        fem_impact.run(case, stop_on_energy_gain=True)
    assert isinstance(info.value, FemImpactError) and "energy" in str(info.value)
    assert files_under(tmp_path) == set()


def test_public_names_are_documented():
    for name in fem_impact.__all__:
        obj = getattr(fem_impact, name)
        if name != "__version__":
            assert (obj.__doc__ or "").strip(), f"fem_impact.{name} has no docstring"
    for method in ("from_dict", "with_changes", "resolved", "write_resolved", "error"):
        assert getattr(Case, method).__doc__, f"Case.{method} has no docstring"
    assert fem_impact.Result.__doc__ and fem_impact.Result.history.__doc__


def test_importing_the_package_stays_light():
    """``import fem_impact`` (and load_case) must not load dolfinx or PETSc: bad input fails fast."""
    import subprocess
    import sys

    code = ("import sys, fem_impact; fem_impact.load_case(sys.argv[1]); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('dolfinx', 'petsc4py', 'ufl')))")
    out = subprocess.run([sys.executable, "-c", code, str(CASES / "vibrodrive.yaml")], capture_output=True,
                         text=True, env={**os.environ, "PYTHONPATH": str(Path(fem_impact.__file__).parents[1])})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("solver", [{"method": "moreau_jean"}, {"method": "moreau_jean", "restitution": 0.5},
                                    {"method": "moreau_jean", "level": "velocity"}, {"method": "newmark"},
                                    {"method": "central_difference", "dt": 0.01},
                                    {"method": "modal", "modes": 20}])
def test_history_impulses_close_the_momentum_balance(solver):
    """The free bar's momentum changes by the wall's total impulse, exactly (every impulse a step
    applies is in the history: Carnot's correction too)."""
    solver = dict(solver)
    restitution = solver.pop("restitution", 0.0)
    data = {**B2A, "mesh": {"shape": "bar", "cells": 50}, "solver": {"dt": 0.02, "t_end": 3.0, **solver},
            "contacts": [{**B2A["contacts"][0], "restitution": restitution}]}
    h = fem_impact.run(Case.from_dict(data)).history
    assert h["wall.impulse"].sum() > 1.5
    assert h["wall.impulse"].sum() == pytest.approx(h["bar.px"][-1] - h["bar.px"][0], rel=1e-9)


# --- one exception policy (issue 16): CaseError, SimulationError, or a TypeError that says what is expected -----

SMALL = {**B2A, "mesh": {"shape": "bar", "cells": 10}, "solver": {"dt": 0.1, "t_end": 0.3},
         "output": {"vtk": False}}
RUN_TAKES = "run() takes a Case: fem_impact.load_case(path) or Case.from_dict(data), got "
CHANGES_TAKE = "Case.with_changes() takes a mapping {'key.path': value} or a list of 'KEY.PATH=VALUE' strings, got "


def wrong_types():
    """(call, the TypeError's message) for every public entry point given a wrong Python type."""
    case = Case.from_dict(SMALL)
    path = CASES / "impacting_bar.yaml"
    return [
        (lambda: fem_impact.run(None), RUN_TAKES + "None"),
        (lambda: fem_impact.run(dict(SMALL)), RUN_TAKES + "dict"),
        (lambda: fem_impact.run("case.yaml"), RUN_TAKES + "str"),
        (lambda: fem_impact.run(case, outdir=5),
         "run() takes outdir as a folder (str or os.PathLike) or None, got int"),
        (lambda: fem_impact.run(case, comm="world"),
         "run() takes comm as an mpi4py communicator (e.g. MPI.COMM_WORLD) or None, got str"),
        (lambda: fem_impact.run(case, progress="yes"), "run() takes progress as true, false or a callable "
                                                       "(step, total), got str"),
        (lambda: fem_impact.run(case, force="no"), "run() takes force as true or false, got str"),
        (lambda: fem_impact.run(case, stop_on_energy_gain=None),
         "run() takes stop_on_energy_gain as true or false, got None"),
        (lambda: Case.from_dict([1, 2]), "Case.from_dict() takes a mapping of the case's keys, got list"),
        (lambda: Case.from_dict(None), "Case.from_dict() takes a mapping of the case's keys, got None"),
        (lambda: Case.from_dict(SMALL, base_dir=5),
         "Case.from_dict() takes base_dir as a folder (str or os.PathLike) or None, got int"),
        (lambda: case.with_changes(None), CHANGES_TAKE + "None"),
        (lambda: case.with_changes("solver.dt=0.01"), CHANGES_TAKE + "str"),
        (lambda: case.with_changes([("solver.dt", 0.01)]), CHANGES_TAKE + "a list holding tuple"),
        (lambda: fem_impact.load_case(5), "load_case() takes a path (str or os.PathLike), got int"),
        (lambda: fem_impact.load_case(path, "solver.dt=0.01"),
         "load_case() takes overrides as a list of 'KEY.PATH=VALUE' strings, got str"),
        (lambda: fem_impact.load_case(path, [1e-3]),
         "load_case() takes overrides as a list of 'KEY.PATH=VALUE' strings, got a list holding float"),
        (lambda: case.write_resolved(None), "Case.write_resolved() takes a path (str or os.PathLike), got None"),
    ]


@pytest.mark.parametrize("index", range(len(wrong_types())))
def test_a_wrong_python_type_is_a_type_error_that_says_what_is_expected(index, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    call, message = wrong_types()[index]
    with pytest.raises(TypeError) as info:
        call()
    assert str(info.value) == message
    assert files_under(tmp_path) == set()


def test_numpy_and_python_containers_are_taken_as_a_case_file_would_give_them():
    """numpy scalars and arrays, tuples, paths and read-only mappings are what a script holds: from_dict and
    with_changes take them as the YAML numbers, lists and mappings they stand for."""
    from types import MappingProxyType

    data = {**SMALL, "mesh": MappingProxyType({"shape": "bar", "cells": np.int64(10), "length": np.float32(1.0)}),
            "material": {"E": np.float64(1.0), "rho": np.int32(1), "area": 1},
            "contacts": ({**SMALL["contacts"][0], "normal": np.array([-1.0])},),
            "output": {"vtk": np.bool_(False), "probes": {"left": (0.0,)}}}
    case = Case.from_dict(data)
    assert (case.mesh.cells, case.mesh.length, case.material.rho) == (10, 1.0, 1.0)
    assert type(case.mesh.cells) is int and case.contacts[0].normal == [-1.0] and case.output.vtk is False
    assert case.with_changes({"mesh.cells": np.int64(20), "solver.dt": np.float64(0.05)}).mesh.cells == 20
    assert Case.from_dict(case.resolved()).resolved() == case.resolved()
    meshes = CASES.parent / "meshes"
    assert Case.from_dict({**SMALL, "mesh": {"file": meshes / "two_bars.msh"}}).mesh.file == meshes / "two_bars.msh"


def test_a_reference_the_case_does_not_fit_is_refused_where_it_is_declared_and_left_behind_by_changes(tmp_path):
    """B1 (a clamped bar released against an obstacle) declared on B2's free bar is bad input, refused with the
    message the studies give (one definition of what fits: fem_impact.references). A benchmark used as a
    template (changes of other keys that take it out of its reference) runs without it, and the studies still
    refuse to measure against it."""
    from fem_impact.references import from_case

    with pytest.raises(CaseError) as declared:
        Case.from_dict({**SMALL, "reference": "b1"})
    b2 = Case.from_dict({**SMALL, "reference": "b2"})
    with pytest.raises(CaseError) as changed:
        b2.with_changes({"reference": "b1"})
    for err in (declared.value, changed.value):
        assert err.key == "reference" and err.message.startswith("b1: needs one support holding x at the other end")
    clamped = b2.with_changes({"supports": [{"nodes": "right", "fix": ["x"]}]})
    assert clamped.reference is None and clamped.resolved()["reference"] is None
    with pytest.raises(CaseError) as study:
        from_case(clamped)
    assert str(study.value) == "reference: b2: is a free bar: remove 'supports'"
    assert fem_impact.run(clamped).summary["steps"] == 3
    assert from_case(clamped.with_changes({"supports": []})).label.startswith("exact b2")   # back in it
    path = tmp_path / "b1.yaml"
    path.write_text(yaml.safe_dump({**SMALL, "reference": "b1"}))
    for overrides in ([], ["solver.dt=0.05"]):   # a file's own reference: the overrides do not excuse it
        with pytest.raises(CaseError, match="b1: needs one support"):
            fem_impact.load_case(path, overrides)


def test_the_final_paragraph_lists_only_the_files_written(tmp_path):
    from fem_impact.app.pipeline import describe

    for vtk in (False, True):
        out = tmp_path / f"vtk-{vtk}"
        summary = fem_impact.run(Case.from_dict({**SMALL, "output": {"vtk": vtk}}), out).summary
        listed = describe(summary).split(f"Results in {summary['outdir']} (")[1].split(")")[0].split(", ")
        assert set(listed) <= {p.name for p in out.iterdir()}, (listed, sorted(p.name for p in out.iterdir()))
        assert ("results.pvd" in listed) == vtk


def test_a_contact_matrix_that_is_not_finite_is_a_simulation_error_naming_it():
    """What the validation cannot see (a mesh file's element sizes, a free body's mass lost beside its stiffness
    at a huge step) can still make the contact problem's matrix infinite or NaN: a SimulationError that says so,
    not numpy's 'SVD did not converge' (small matrices) or a factorization of NaN (large ones)."""
    from fem_impact.nonsmooth.lcp import SMALL, Delassus, regularized

    for A in (np.array([[np.inf]]), np.full((3, 3), np.nan), np.diag(np.r_[np.inf, np.ones(SMALL + 5)])):
        for build in (regularized, Delassus.regularized):
            with pytest.raises(SimulationError, match=rf"contact problem's matrix \(P S\^-1 P\^T, {len(A)} rows\) "
                                                      "is not finite"):
                build(A)


def test_a_free_bar_whose_mass_is_lost_beside_its_stiffness_stops_with_a_simulation_error(tmp_path, monkeypatch):
    """rho = 1e-90 with E = 1 (c = 1e45) at dt = 0.1 on 4 cells: S = M + dt^2 K / 4 holds the free bar's mass
    1e-90 beside stiffness terms of 1e-2, singular to working precision; the run says so (status 3)."""
    monkeypatch.chdir(tmp_path)
    case = Case.from_dict({**SMALL, "mesh": {"shape": "bar", "cells": 4}, "material": {"E": 1.0, "rho": 1e-90}})
    with pytest.raises(SimulationError, match="is not finite: the step matrix S overflowed a float or is singular"):
        fem_impact.run(case)
    assert files_under(tmp_path) == set()


def test_modes_that_are_not_finite_are_a_simulation_error_naming_them(tmp_path, monkeypatch):
    """The reduced model of a bar whose stiffness over mass is 5e-99 (rho = 1e100: within the range): SLEPc's
    vectors come back NaN; the run stops with a SimulationError that says so (scipy's ValueError before)."""
    monkeypatch.chdir(tmp_path)
    case = Case.from_dict({**SMALL, "mesh": {"shape": "bar", "cells": 4}, "material": {"E": 1.0, "rho": 1e100},
                           "solver": {**SMALL["solver"], "method": "modal"}})
    with pytest.raises(SimulationError, match="the eigensolver's vectors are not finite"):
        fem_impact.run(case)
    assert files_under(tmp_path) == set()
