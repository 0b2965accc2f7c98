"""The output folder never destroys what fem-impact did not write (issue 11; fem_impact/outdir.py).

Every command that writes is pointed at folders holding a user's files (the case file itself, notes,
a thesis): each must refuse with one line and status 2 and leave every file byte for byte as it
was; an earlier fem-impact result is replaced; odd paths end in one line, not a traceback; the size
guard refuses absurd runs before anything is built or written.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from conftest import CASES, ROOT

SMALL = ["--set", "mesh.cells=10", "--set", "solver.dt=0.01", "--set", "solver.t_end=0.05", "--set", "output.every=1"]


def cli(*args, cwd=None, env=None):
    env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    return subprocess.run([sys.executable, "-m", "fem_impact", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=300)


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden ones too) with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def user_folder(folder: Path) -> Path:
    """A folder of a user's own work: their case file, notes and a thesis in a subfolder."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(CASES / "impacting_bar.yaml", folder / "own.yaml")
    (folder / "notes.txt").write_text("my notes\n")
    (folder / "chapter").mkdir(exist_ok=True)
    (folder / "chapter" / "thesis.tex").write_text("\\documentclass{article}\n")
    return folder


def refused(result, *words):
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    assert "Traceback" not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fem-impact: error:"), result.stderr
    for word in words:
        assert word in lines[0], lines[0]


def no_debris(parent: Path):
    left = [p.name for p in parent.iterdir() if ".partial-" in p.name or ".old-" in p.name or p.name.endswith(".lock")]
    assert not left, left


# --- the deletion cases of the issue -------------------------------------------------------


@pytest.fixture(scope="module")
def deletions(tmp_path_factory):
    """Each command pointed at a user's folder, run concurrently; (before, after, result) per probe."""
    base = tmp_path_factory.mktemp("deletions")
    probes = {
        "run -o . (cwd = the case's folder)": (lambda d: ("run", "own.yaml", "-o", ".", *SMALL), "cwd"),
        "run -o FOLDER of the case": (lambda d: ("run", d / "own.yaml", "-o", d, *SMALL), None),
        "run -o parent of the case": (lambda d: ("run", d / "own.yaml", "-o", d.parent, *SMALL), None),
        "run -o userdata": (lambda d: ("run", CASES / "impacting_bar.yaml", "-o", d / "chapter", *SMALL), None),
        "run -o ~": (lambda d: ("run", CASES / "impacting_bar.yaml", "-o", "~", *SMALL), "home"),
        "run -o $HOME": (lambda d: ("run", CASES / "impacting_bar.yaml", "-o", d, *SMALL), "home"),
        "sweep -o the case's folder": (lambda d: ("sweep", d / "own.yaml", "--vary", "solver.dt=0.01,0.02",
                                                  "-o", d, *SMALL[:2]), None),
        "modes -o userdata": (lambda d: ("modes", d / "own.yaml", "-n", "2", "-o", d / "chapter", *SMALL[:2]), None),
        "reduction -o userdata": (lambda d: ("reduction", d / "own.yaml", "--modes", "2", "-o", d / "chapter",
                                             *SMALL), None),
        "study -o userdata": (lambda d: ("study", "convergence", d / "own.yaml", "--vary", "mesh.cells=10,20",
                                         "-o", d / "chapter", *SMALL[2:]), None),
    }

    def one(item):
        i, (name, (args, mode)) = item
        d = user_folder(base / f"p{i}" / "user")
        cwd = d if mode == "cwd" else base
        args = args(d)
        if mode == "home":   # the home folder is the user's folder; "~" is expanded by the shell, not us
            args = tuple(str(d) if a == "~" else a for a in args)
        before = snapshot(d.parent)
        result = cli(*args, cwd=cwd, env={"HOME": str(d)} if mode == "home" else None)
        return name, (before, snapshot(d.parent), result, d)

    with ThreadPoolExecutor(4) as pool:
        return dict(pool.map(one, enumerate(probes.items())))


@pytest.mark.parametrize("probe", [
    "run -o . (cwd = the case's folder)", "run -o FOLDER of the case", "run -o parent of the case", "run -o userdata",
    "run -o $HOME", "sweep -o the case's folder", "modes -o userdata", "reduction -o userdata", "study -o userdata"])
def test_user_folder_survives(deletions, probe):
    before, after, result, folder = deletions[probe]
    refused(result)
    assert after == before   # the case file, the notes and the thesis, byte for byte; nothing added
    assert (folder / "own.yaml").is_file() and (folder / "chapter" / "thesis.tex").is_file()


def test_root_is_refused(tmp_path):
    result = cli("run", CASES / "impacting_bar.yaml", "-o", "/", *SMALL, cwd=tmp_path)
    refused(result, "/")
    assert not list(Path("/").glob("..partial-*")) and not list(Path("/").glob(".*.lock"))


def test_earlier_result_is_replaced_and_marked(tmp_path):
    out = tmp_path / "out"
    first = cli("run", CASES / "impacting_bar.yaml", "-o", out, *SMALL)
    assert first.returncode == 0, first.stderr
    assert (out / ".fem-impact.json").is_file()
    (out / "history.csv").write_text("stale\n")
    second = cli("run", CASES / "impacting_bar.yaml", "-o", out, *SMALL, "-q")
    assert second.returncode == 0, second.stderr
    assert (out / "history.csv").read_text() != "stale\n"
    no_debris(tmp_path)
    # a result of a version before the marker (summary.json with fem_impact_version) is replaced too
    (out / ".fem-impact.json").unlink()
    third = cli("run", CASES / "impacting_bar.yaml", "-o", out, *SMALL, "-q")
    assert third.returncode == 0, third.stderr
    # an empty folder is fine
    (tmp_path / "empty").mkdir()
    assert cli("run", CASES / "impacting_bar.yaml", "-o", tmp_path / "empty", *SMALL, "-q").returncode == 0


def test_file_outputs_do_not_overwrite_user_files(tmp_path):
    out = tmp_path / "run"
    assert cli("run", CASES / "impacting_bar.yaml", "-o", out, *SMALL, "-q").returncode == 0
    thesis = tmp_path / "thesis.png"   # a user's file with a picture's name, that is not a picture
    thesis.write_text("not a picture\n")
    refused(cli("plot", out, "-o", thesis), "thesis.png")
    refused(cli("animate", out, "-o", thesis), "thesis.png")
    assert thesis.read_text() == "not a picture\n"
    refused(cli("plot", out, "-o", out / "history.csv"))
    ok = cli("plot", out, "-o", tmp_path / "h.png")
    assert ok.returncode == 0 and (tmp_path / "h.png").read_bytes().startswith(b"\x89PNG")
    assert cli("plot", out, "-o", tmp_path / "h.png").returncode == 0   # its own picture: replaced
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.png", "run", "thesis.png"]


def test_a_second_run_into_a_locked_folder_refuses(tmp_path):
    out = tmp_path / "out"
    lock = tmp_path / ".out.lock"
    with open(lock, "w") as f:   # as a running fem-impact holds it
        fcntl.flock(f, fcntl.LOCK_EX)
        f.write("12345\n")
        f.flush()
        refused(cli("run", CASES / "impacting_bar.yaml", "-o", out, *SMALL), "another fem-impact process",
                "12345")
    assert not out.exists()
    assert cli("run", CASES / "impacting_bar.yaml", "-o", out, *SMALL, "-q").returncode == 0
    no_debris(tmp_path)


# --- odd output paths: one line, not a traceback -------------------------------------------


@pytest.fixture(scope="module")
def odd_paths(tmp_path_factory):
    base = tmp_path_factory.mktemp("odd")
    (base / "afile").write_text("x\n")
    run_dir = base / "run"
    assert cli("run", CASES / "impacting_bar.yaml", "-o", run_dir, *SMALL, "-q").returncode == 0
    bad_history = base / "bad"
    bad_history.mkdir()
    (bad_history / "history.csv").write_text("t,kinetic\n0.0,abc\n")
    calls = {
        "/proc/x": ("run", CASES / "impacting_bar.yaml", "-o", "/proc/x", *SMALL),
        "/sys/x": ("run", CASES / "impacting_bar.yaml", "-o", "/sys/x", *SMALL),
        "afile/sub": ("run", CASES / "impacting_bar.yaml", "-o", base / "afile" / "sub", *SMALL),
        "afile": ("run", CASES / "impacting_bar.yaml", "-o", base / "afile", *SMALL),
        "empty": ("run", CASES / "impacting_bar.yaml", "-o", "", *SMALL),
        "long name": ("run", CASES / "impacting_bar.yaml", "--set", "name=" + "c" * 300, *SMALL),   # default -o
        "plot -o /proc/x.png": ("plot", run_dir, "-o", "/proc/x.png"),
        "plot non-number": ("plot", bad_history),
        "plot unknown format": ("plot", run_dir, "-o", base / "h.xyz"),
    }
    with ThreadPoolExecutor(4) as pool:
        results = dict(zip(calls, pool.map(lambda a: cli(*a, cwd=base), calls.values()), strict=True))
    return base, results


@pytest.mark.parametrize("probe", ["/proc/x", "/sys/x", "afile/sub", "afile", "empty", "long name",
                                   "plot -o /proc/x.png", "plot non-number", "plot unknown format"])
def test_odd_paths_are_one_line(odd_paths, probe):
    base, results = odd_paths
    refused(results[probe])
    if probe == "long name":
        assert not (base / "results").exists()   # no empty results/ left behind
    assert (base / "afile").read_text() == "x\n"


# --- the size guard ----------------------------------------------------------------------------


def test_size_guard_refuses_before_anything_is_written(tmp_path):
    steps = cli("run", CASES / "impacting_bar.yaml", "-o", tmp_path / "a", "--set", "solver.dt=1e-12")
    refused(steps, "solver.dt", "4e+12 steps", "--force")
    memory = cli("run", CASES / "impacting_bar.yaml", "-o", tmp_path / "b", "--set", "mesh.cells=1000000000")
    refused(memory, "mesh.cells", "memory", "--force")
    frames = cli("run", CASES / "impacting_bar.yaml", "-o", tmp_path / "c", "--set", "solver.dt=1e-6",
                 "--set", "output.every=1")
    refused(frames, "output.every", "VTK frames")
    assert list(tmp_path.iterdir()) == []


def test_size_guard_estimate_and_force():
    from mpi4py import MPI

    from fem_impact.case import CaseError, load_case
    from fem_impact.limits import MAX_STEPS, check_limits, estimate

    case = load_case(CASES / "impacting_bar.yaml", ["solver.dt=1e-12"])
    est = estimate(case)
    assert est.steps == 4 * 10**12 and est.nodes == 251 and est.steps > MAX_STEPS
    with pytest.raises(CaseError, match="solver.dt"):
        check_limits(case, Path("/tmp/x"), MPI.COMM_SELF)
    assert check_limits(case, Path("/tmp/x"), MPI.COMM_SELF, force=True).steps == est.steps
    # 2D and 3D bars: cells along times cells across (length / 20 by default) plus one, per axis
    assert estimate(load_case(CASES / "impacting_bar.yaml", ["mesh.dim=2", "mesh.cells=200"])).nodes == 201 * 11
    assert estimate(load_case(CASES / "impacting_bar.yaml", ["mesh.dim=3", "mesh.cells=40"])).nodes == 41 * 3 * 3
    # every case of the project passes the guard as written
    for path in sorted(CASES.glob("*.yaml")):
        check_limits(load_case(path), Path("/tmp/x"), MPI.COMM_SELF)


def test_memory_exhaustion_during_setup_is_one_line(tmp_path):
    """Past the guard (--force) with too little memory (an address-space limit of 3 GB): one line, status 2."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (3 * 10**9, 3 * 10**9))

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-m", "fem_impact", "run", str(CASES / "impacting_bar.yaml"), "-o",
                             str(tmp_path / "out"), "--set", "mesh.cells=200000000", "--force", "-q"],
                            capture_output=True, text=True, env=env, preexec_fn=limit, timeout=300)
    refused(result, "not enough memory")
    assert list(tmp_path.iterdir()) == []
