"""Fuzzing the loader (issue 11) and the API and command line (issue 16): bad input ends in a clean error.

Issue 11: Hypothesis mutates the project's own case files: a value anywhere replaced by another type or an
extreme number, a key dropped or added, the structure nested, the text's bytes and encoding
changed, random ``--set`` options. For each: ``load_case`` and the size guard either accept the case
or raise CaseError (the command line's status 2: one line naming file and key, no traceback), and
nothing is written. Issue 16 (below): the API with numeric extremes and wrong types, valid cases at the
edges of the numeric range, damaged mesh files, --set values through the command. The default tier
runs a few hundred examples; ``-m slow`` a few thousand.
"""

from __future__ import annotations

import gc
import math
import os
import tempfile
from pathlib import Path

import pytest
import yaml

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from conftest import CASES, ROOT  # noqa: E402

BASES = {p.name: yaml.safe_load(p.read_text()) for p in sorted(CASES.glob("*.yaml"))
         if "file" not in (yaml.safe_load(p.read_text()).get("mesh") or {})}   # (mesh files: see below)
KEYS = ["name", "mesh.dim", "mesh.cells", "mesh.length", "mesh.height", "mesh.width", "mesh.shape", "mesh.file",
        "material.E", "material.rho", "material.nu", "material.area", "initial.velocity", "initial.velocity.0",
        "initial.displacement", "supports", "loads", "contacts", "contacts.0.normal", "contacts.0.gap",
        "contacts.0.restitution", "contacts.0.nodes", "solver.dt", "solver.t_end", "solver.method", "solver.modes",
        "solver.beta", "solver.gamma", "output.every", "output.probes", "output.probes.left", "parameters.f",
        "damping.alpha", "reference", "nothing.here", "contacts.7.gap", ".", "a..b"]

numbers = st.one_of(st.integers(), st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from([0, -1, 1e-300, 1e300, 2**63, -(2**63), 1e-12, 1e12, 1e9, 0.5, 3]))
scalars = st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=20),
                    st.sampled_from(["all", "x", "w", "bar", "left", "newmark", "modal", "auto", "sin(t)", "1/0",
                                     "x**x**x**x", "__import__('os')", "\0", "\ud800", "1e400", "9" * 400]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                        st.dictionaries(st.text(max_size=8), inner, max_size=4)),
                      max_leaves=12)


def paths(data, prefix=()):
    """Every key path of a nested structure (mappings and lists)."""
    yield prefix
    if isinstance(data, dict):
        for k, v in data.items():
            yield from paths(v, prefix + (k,))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            yield from paths(v, prefix + (i,))


def mutate(data, path, how, value):
    if not path:
        return value if how == "replace" else data
    parent = data
    for part in path[:-1]:
        parent = parent[part]
    last = path[-1]
    if how == "replace":
        parent[last] = value
    elif how == "delete":
        del parent[last]
    elif how == "nest":
        parent[last] = [parent[last]] if isinstance(parent, dict) else {"x": parent[last]}
    elif how == "add" and isinstance(parent, dict):
        parent[f"extra_{value!s:.8}"] = value
    return data


@st.composite
def case_texts(draw):
    """(file bytes, --set options) of a mutated case file."""
    import copy

    base = copy.deepcopy(BASES[draw(st.sampled_from(sorted(BASES)))])
    for _ in range(draw(st.integers(0, 3))):
        path = draw(st.sampled_from(list(paths(base))))
        base = mutate(base, path, draw(st.sampled_from(["replace", "delete", "nest", "add"])), draw(values))
    try:
        text = yaml.safe_dump(base, sort_keys=False, allow_unicode=True)
    except Exception:   # (a value PyYAML cannot dump: skip, not the loader's concern)
        text = "name: x\n"
    raw = text.encode("utf-8", "surrogatepass")
    edit = draw(st.sampled_from(["none", "none", "bytes", "encoding", "truncate", "text"]))
    if edit == "bytes":
        at = draw(st.integers(0, len(raw)))
        raw = raw[:at] + draw(st.binary(max_size=8)) + raw[at:]
    elif edit == "encoding":
        raw = text.encode(draw(st.sampled_from(["utf-16", "utf-32", "latin-1", "cp1252"])), "replace")
    elif edit == "truncate":
        raw = raw[:draw(st.integers(0, len(raw)))]
    elif edit == "text":
        at = draw(st.integers(0, len(text)))
        raw = (text[:at] + draw(st.text(alphabet=":-[]{}&*!|>'\"#%@` \n\t,?", max_size=6)) + text[at:]).encode()
    options = draw(st.lists(st.tuples(st.sampled_from(KEYS), st.one_of(
        st.text(max_size=20), values.map(lambda v: yaml.safe_dump(v, default_flow_style=True).strip()
                                        if _dumpable(v) else "x"))).map(lambda kv: f"{kv[0]}={kv[1]}"),
        max_size=2))
    return raw, options


def _dumpable(v) -> bool:
    try:
        yaml.safe_dump(v)
        return True
    except Exception:
        return False


def check_one(raw: bytes, options) -> None:
    from mpi4py import MPI

    from fem_impact.config.case import CaseError, load_case
    from fem_impact.app.limits import check_limits

    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        path = folder / "case.yaml"
        path.write_bytes(raw)
        try:
            case = load_case(path, options)
            check_limits(case, folder / "out", MPI.COMM_SELF)
        except CaseError as err:
            message = str(err)
            assert message and "\n" not in message and "Traceback" not in message, message
            assert len(message) < 2000, message[:300]
        assert sorted(os.listdir(folder)) == ["case.yaml"]   # nothing written
        assert path.read_bytes() == raw


FAST = settings(max_examples=300, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
LONG = settings(max_examples=5000, deadline=None, suppress_health_check=list(HealthCheck))


@FAST
@given(case_texts())
def test_mutated_cases_load_or_fail_cleanly(sample):
    check_one(*sample)


@pytest.mark.slow
@LONG
@given(case_texts())
def test_mutated_cases_load_or_fail_cleanly_long(sample):
    check_one(*sample)


@FAST
@given(st.sampled_from(sorted(BASES)), st.lists(st.tuples(st.sampled_from(KEYS), st.text(max_size=30)), max_size=3))
def test_set_values_load_or_fail_cleanly(name, options):
    """Any text after ``--set KEY=``: a value typed as in YAML, or a clean error."""
    check_one((CASES / name).read_bytes(), [f"{k}={v}" for k, v in options])


def test_the_fuzzer_reaches_both_outcomes():
    """The mutations are not all rejected (or all accepted): the property tests see both outcomes."""
    from fem_impact.config.case import CaseError, load_case

    good = (CASES / "impacting_bar.yaml").read_bytes()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "case.yaml"
        path.write_bytes(good)
        assert load_case(path, ["solver.dt=0.001"]).solver.dt == 0.001
        with pytest.raises(CaseError):
            load_case(path, ["solver.dt=-1"])
    assert math.isfinite(len(BASES)) and len(BASES) >= 5


# --- the Python API and the command line with numeric extremes, wrong types and damaged meshes (issue 16) -------
#
# The policy (docs/running.md, bad input and exit statuses): bad data raises CaseError naming the key, a run that cannot go on raises
# SimulationError, an argument of a wrong Python type raises a TypeError that names the function and what it
# takes; nothing else escapes. Cases are tiny (10 cells, 3 steps): most examples fail validation, and the few
# that run take a fraction of a second.

API_FAST = settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
API_LONG = settings(max_examples=3000, deadline=None, suppress_health_check=list(HealthCheck))

TINY = {"name": "tiny", "mesh": {"shape": "bar", "cells": 10},
        "material": {"E": 1.0, "rho": 1.0, "area": 1.0},
        "initial": {"velocity": [-1.0]},
        "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0], "gap": 0.05}],
        "solver": {"method": "newmark", "dt": 0.1, "t_end": 0.3},
        "output": {"vtk": False, "probes": {"left": [0.0]}}}
API_KEYS = ["mesh.cells", "mesh.length", "mesh.dim", "mesh.height", "mesh.width", "material.E", "material.rho",
            "material.area", "material.nu", "damping.alpha", "damping.beta", "initial.velocity.0",
            "initial.displacement", "contacts.0.gap", "contacts.0.normal.0", "contacts.0.stiffness",
            "contacts.0.restitution", "solver.dt", "solver.t_end", "solver.beta", "solver.gamma", "solver.method",
            "output.every", "output.probes.left.0", "parameters.p", "reference", "name", "new_key"]


class Huge(int):
    """An integer too long for Python to print (over 4300 digits), shown by its exponent (for Hypothesis)."""

    def __repr__(self):
        return "10**5000"


EXTREMES = [1e308, -1e308, 1.7976931348623157e308, 5e-324, -5e-324, 1e-320, 2.2250738585072014e-308, 1e-310,
            0.0, -0.0, 1e150, 1e-150, 1e151, 1e-151, 1e154, 1e-154, 10**400, -(10**400), Huge(10**5000), 2**63,
            2**31, math.nan, math.inf, -math.inf]
WRONG = [None, True, "", "x", b"bytes", [], {}, [1, 2], {"a": 1}, object(), (1,), {1, 2}, 1j, Path("p")]


def _numpy(value):
    import numpy as np

    return np.float64(value) if isinstance(value, float) else np.int64(value) if abs(value) < 2**63 else value


api_numbers = st.one_of(st.sampled_from(EXTREMES), st.floats(), st.integers(),
                        st.floats(min_value=1e-3, max_value=10.0),   # (plausible: some cases run)
                        st.sampled_from(EXTREMES).filter(lambda v: not isinstance(v, float) or math.isfinite(v))
                        .map(_numpy))
api_values = st.one_of(api_numbers, st.sampled_from(WRONG),
                       st.sampled_from(["newmark", "moreau_jean", "central_difference", "modal", "b1", "b2",
                                        "bar_mode", "1e308*x", "x/0", "a\nb", "9" * 5000]),
                       st.lists(api_numbers, max_size=3))


def _set(data: dict, key: str, value) -> None:
    *parents, last = key.split(".")
    for part in parents:
        data = data[int(part)] if isinstance(data, list) else data.setdefault(part, {})
        if not isinstance(data, (dict, list)):
            return
    if isinstance(data, list):
        if int(last) < len(data):
            data[int(last)] = value
    else:
        data[last] = value


def _assert_clean(err: BaseException) -> None:
    """A FemImpactError of one line; anything else is a defect (re-raised for Hypothesis to shrink)."""
    from fem_impact import FemImpactError

    if not isinstance(err, FemImpactError):
        raise err
    message = str(err)
    assert message and "\n" not in message and len(message) < 2000, message[:300]


def _run_if_tiny(case) -> None:
    """Run a valid case when it is tiny (nothing written); else only the size guard."""
    from mpi4py import MPI

    import fem_impact
    from fem_impact.app.limits import check_limits, estimate

    est = estimate(case)
    if est.dofs <= 200 and est.steps <= 20 and not case.output.vtk:
        try:
            fem_impact.run(case)
        finally:
            gc.collect()   # (a failed run's PETSc objects, collected later at an unlucky moment, can crash: DRIVER)
    else:
        check_limits(case, None, MPI.COMM_SELF)


def check_api_case(changes, through_changes: bool) -> None:
    import copy
    import warnings

    from fem_impact import Case

    data = copy.deepcopy(TINY)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # (overflow on the way to a blow-up: reported as such)
        try:
            if through_changes:
                case = Case.from_dict(data).with_changes(dict(changes))
            else:
                for key, value in changes:
                    _set(data, key, value)
                case = Case.from_dict(data)
            _run_if_tiny(case)
        except Exception as err:   # noqa: BLE001 - the property: only FemImpactError may come out
            _assert_clean(err)


api_changes = st.lists(st.tuples(st.sampled_from(API_KEYS), api_values), min_size=1, max_size=3)


@API_FAST
@given(api_changes, st.booleans())
def test_api_cases_with_extreme_values_run_or_fail_cleanly(changes, through_changes):
    check_api_case(changes, through_changes)


@pytest.mark.slow
@API_LONG
@given(api_changes, st.booleans())
def test_api_cases_with_extreme_values_run_or_fail_cleanly_long(changes, through_changes):
    check_api_case(changes, through_changes)


any_value = st.one_of(st.sampled_from(WRONG), st.integers(), st.floats(), st.text(max_size=8), st.binary(max_size=4),
                      st.lists(st.integers(), max_size=2), st.dictionaries(st.text(max_size=3), st.integers(),
                                                                             max_size=2))
# (entry point, its name in a TypeError, the arguments: each either a good one or any value)
ENTRY_POINTS = ["load_case", "from_dict", "with_changes", "run", "write_resolved", "error"]
CALLS = {"load_case": "load_case()", "from_dict": "Case.from_dict()", "with_changes": "Case.with_changes()",
         "run": "run()", "write_resolved": "Case.write_resolved()", "error": "Case.error()"}


def check_api_call(entry: str, arguments: list, folder: Path) -> None:
    from mpi4py import MPI

    import fem_impact
    from fem_impact import Case

    case = Case.from_dict(TINY)
    good = {"load_case": [str(CASES / "impacting_bar.yaml"), ["mesh.cells=10"]], "from_dict": [TINY, None],
            "with_changes": [{"solver.dt": 0.05}], "run": [case, None, False, MPI.COMM_SELF, False, False],
            "write_resolved": [folder], "error": [("material", "E"), "message"]}[entry]
    args = [value if wrong else good[i] for i, (wrong, value) in enumerate(arguments[:len(good)])]
    call = {"load_case": fem_impact.load_case, "from_dict": Case.from_dict, "with_changes": case.with_changes,
            "run": fem_impact.run, "write_resolved": case.write_resolved, "error": case.error}[entry]
    try:
        result = call(*args)
    except TypeError as err:
        assert str(err).startswith(f"{CALLS[entry]} takes "), f"{entry}{tuple(args)!r}: {err}"
        return
    except Exception as err:   # noqa: BLE001
        _assert_clean(err)
        return
    if entry == "run":
        assert isinstance(result, fem_impact.Result)


def check_api_calls(entry, arguments) -> None:
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as folder:
        os.chdir(folder)
        try:
            check_api_call(entry, arguments, Path(folder))
        finally:
            os.chdir(cwd)


api_arguments = st.lists(st.tuples(st.booleans(), any_value), min_size=6, max_size=6)


@API_FAST
@given(st.sampled_from(ENTRY_POINTS), api_arguments)
def test_api_entry_points_with_wrong_types_raise_clear_errors(entry, arguments):
    check_api_calls(entry, arguments)


@pytest.mark.slow
@API_LONG
@given(st.sampled_from(ENTRY_POINTS), api_arguments)
def test_api_entry_points_with_wrong_types_raise_clear_errors_long(entry, arguments):
    check_api_calls(entry, arguments)


# Batches of commands: one interpreter runs each through the command's code (cli.main) and reports its
# outcome on a line; a crash of the interpreter shows as the command it was running. (A collection of
# the previous runs' garbage after each: in a long-lived interpreter, failed runs' PETSc objects collected
# at an unlucky moment can crash a later factorization; reported apart, not the subject here.)
DRIVER = """
import gc, json, os, sys, traceback
from fem_impact.app.cli import main
for index, argv in enumerate(json.loads(sys.argv[1])):
    print("try", index, flush=True)
    try:
        status = main(argv)
    except BaseException:
        print("traceback", index, json.dumps(traceback.format_exc()), flush=True)
        continue
    print("status", status, index, flush=True)
    gc.collect()
os._exit(0)   # (the command runs once per interpreter: no teardown of many runs' PETSc and Gmsh objects)
"""


def run_batch(commands: list, folder) -> None:
    """Run ``fem-impact ARGS`` for each list of arguments in one interpreter: status 0, 2 or 3, no traceback."""
    import json
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(commands)], capture_output=True, text=True,
                          cwd=folder, timeout=900)
    tried = [int(line.split()[1]) for line in proc.stdout.splitlines() if line.startswith("try ")]
    last = commands[tried[-1]] if tried else None
    assert proc.returncode == 0, f"the interpreter died ({proc.returncode}) on {last}: {proc.stderr[-500:]}"
    tracebacks = [line for line in proc.stdout.splitlines() if line.startswith("traceback ")]
    assert not tracebacks, (commands[int(tracebacks[0].split()[1])], tracebacks[0][:2000])
    statuses = [int(line.split()[1]) for line in proc.stdout.splitlines() if line.startswith("status ")]
    assert len(statuses) == len(commands) and set(statuses) <= {0, 2, 3}, proc.stdout[-2000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]


# (A batch is drawn from a seed: Hypothesis's first example of a list of draws is its simplest, all alike.)
BATCH, SHORT_BATCH = 15, 6   # commands per interpreter: the slow tier's, the default tier's


def check_damaged_meshes(seed: int, size: int = BATCH) -> None:
    import random

    rng = random.Random(seed)
    lines = (ROOT / "meshes" / "two_bars.msh").read_bytes().split(b"\n")
    with tempfile.TemporaryDirectory() as folder:
        commands = []
        for index in range(size):
            how = rng.choice(["delete", "duplicate", "replace", "truncate", "bytes"])
            text = rng.choice([b"-1", b"1e308", b"nan", b"x", b"99999999999", b"0", b"", b"$EndNodes",
                               b"\x00\xff\xfe", b"1 2 3 4 5 6 7 8 9"])
            damaged = list(lines)
            at = rng.randrange(len(damaged))
            if how == "delete":
                del damaged[at]
            elif how == "duplicate":
                damaged.insert(at, damaged[at])
            elif how == "replace":
                damaged[at] = text
            elif how == "truncate":
                damaged = damaged[:at]
            else:
                damaged[at] = damaged[at][:3] + text + damaged[at][3:]
            path = Path(folder) / f"damaged{index}.msh"
            path.write_bytes(b"\n".join(damaged))
            commands.append(["run", str(CASES / "two_bars.yaml"), "-q", "-o", f"out{index}", "--set",
                             f"mesh.file={path}", "--set", "solver.t_end=0.02", "--set", "output.vtk=false"])
        run_batch(commands, folder)


@settings(max_examples=1, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_damaged_mesh_files_are_refused_cleanly(seed):
    check_damaged_meshes(seed, SHORT_BATCH)


@pytest.mark.slow
@settings(max_examples=20, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.integers(0, 2**32 - 1))
def test_damaged_mesh_files_are_refused_cleanly_long(seed):
    check_damaged_meshes(seed)


# Valid cases at the edges of the numeric range (every method and dimension, values from 1e-100 to 1e+100):
# they run, or stop with one line (status 2 before anything runs, 3 during the run); in batches, as above.
EDGE_KEYS = ["material.E", "material.rho", "material.area", "mesh.length", "damping.alpha", "damping.beta",
             "contacts.0.gap", "contacts.0.stiffness", "initial.velocity", "solver.dt"]
EDGE_VALUES = [1e100, 1e-100, 1e80, 1e-80, 1e50, 1e-50, 1e20, 1e-20]


def check_edge_runs(seed: int, size: int = BATCH) -> None:
    import random

    rng = random.Random(seed)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "tiny.yaml"
        path.write_text(yaml.safe_dump(TINY))
        commands = []
        for index in range(size):
            method = rng.choice(["moreau_jean", "newmark", "central_difference", "modal"])
            options = [f"solver.method={method}", f"mesh.dim={rng.choice([1, 1, 2, 3])}", "mesh.cells=4"]
            for key in rng.sample(EDGE_KEYS, rng.randint(1, 3)):
                value = rng.choice(EDGE_VALUES)
                if key == "solver.dt":
                    options += [f"solver.dt={value!r}", f"solver.t_end={3 * value!r}"]
                else:
                    options.append(f"initial.velocity=[{value!r}]" if key == "initial.velocity" else f"{key}={value!r}")
            commands.append(["run", str(path), "-q", "-o", f"out{index}", *(a for o in options for a in ("--set", o))])
        run_batch(commands, folder)


@settings(max_examples=1, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_cases_at_the_edges_of_the_numeric_range_run_or_stop_with_one_line(seed):
    check_edge_runs(seed, SHORT_BATCH)


@pytest.mark.slow
@settings(max_examples=20, deadline=None, suppress_health_check=list(HealthCheck))
@given(st.integers(0, 2**32 - 1))
def test_cases_at_the_edges_of_the_numeric_range_run_or_stop_with_one_line_long(seed):
    check_edge_runs(seed)


# The command line itself: fuzzed --set values in a fresh interpreter each (about 1.5 s), a few by default.
SET_VALUES = ["1e308", "-1e308", "1e-320", "5e-324", "-0.0", ".nan", ".inf", "9" * 5000, "1e400", "[1e308]",
              "{a: 1}", "", "~", "0x10", "[]", "'a\\nb'", "2147483648", "1e150", "1e-150", "newmark", "b1", "\udcff"]
# (A command line cannot hold a NUL byte: the operating system refuses it before the program starts. It holds
# bytes: one that is not UTF-8 reaches Python as a surrogate escape, "\udcff" above; a lone surrogate of any other
# kind cannot be on it, and the test could not pass one to the child.)
set_options = st.lists(st.tuples(st.sampled_from(API_KEYS), st.one_of(
    st.sampled_from(SET_VALUES), st.text(st.characters(blacklist_characters="\x00", blacklist_categories=("Cs",)),
                                         max_size=12))),
    min_size=1, max_size=3)


def check_command(options) -> None:
    from conftest import run_cli

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "tiny.yaml"
        path.write_text(yaml.safe_dump(TINY))
        args = [a for key, value in options for a in ("--set", f"{key}={value}")]
        proc = run_cli("run", str(path), "-q", "-o", str(Path(folder) / "out"), *args)
        assert proc.returncode in (0, 2, 3), (proc.returncode, proc.stderr[-2000:])
        assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
        assert len(proc.stderr.strip().splitlines()) <= 2, proc.stderr[-2000:]


@settings(max_examples=3, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(set_options)
def test_command_line_with_extreme_set_values_has_no_traceback(options):
    check_command(options)


@pytest.mark.slow
@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(set_options)
def test_command_line_with_extreme_set_values_has_no_traceback_long(options):
    check_command(options)
