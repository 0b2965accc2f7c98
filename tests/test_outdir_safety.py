"""The output folder never destroys what fem-impact did not write (fem_impact/app/outdir/).

Every command that writes is pointed at folders holding a user's files (the case file itself, notes,
a thesis): each must refuse with one line and status 2 and leave every file byte for byte as it
was; an earlier fem-impact result is replaced; odd paths end in one line, not a traceback; the size
guard refuses absurd runs before anything is built or written.
"""

from __future__ import annotations

import errno
import fcntl
import os
import shutil
import subprocess
import sys
import types
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from conftest import CASES, ROOT

# One worker takes the whole module (make test runs --dist loadgroup):
# its module fixtures run the command line (5 s), once, not once in each worker.
pytestmark = pytest.mark.xdist_group("outdir_safety")

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

    from fem_impact.config.case import CaseError, load_case
    from fem_impact.app.limits import MAX_STEPS, check_limits, estimate

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


# --- the policy checked again at the final move (issue 16) -----------------------------------

def small_case():
    from fem_impact import load_case

    return load_case(CASES / "impacting_bar.yaml", [a for a in SMALL if a != "--set"])


def at_step(k, action):
    """A progress callback that does ``action`` once, at step ``k`` of the time loop (inside the run)."""
    def progress(step, total):
        if step == k:
            action()
    return progress


def kept_results(parent: Path) -> list[Path]:
    return sorted(parent.glob("*.result-*"))


@pytest.mark.parametrize("earlier", [False, True], ids=["new folder", "earlier result"])
def test_a_folder_made_during_the_run_is_left_and_the_result_kept_beside(tmp_path, earlier):
    """The issue's race: while the run integrates, the user makes the output folder (or empties the
    earlier result) and puts a file in it. The run must not replace it: the file stays, the result is
    kept beside it and the error says where."""
    import fem_impact
    from fem_impact.app.outdir.manifest import is_result
    from fem_impact.app.outdir.policy import OutputFolderChanged

    out = tmp_path / "out"
    if earlier:
        fem_impact.run(small_case(), out)

    def user_takes_the_folder():
        if out.exists():
            shutil.rmtree(out)
        out.mkdir()
        (out / "notes.txt").write_text("my notes\n")

    with pytest.raises(OutputFolderChanged) as caught:
        fem_impact.run(small_case(), out, progress=at_step(2, user_takes_the_folder))
    assert snapshot(out) == {"notes.txt": b"my notes\n"}
    kept = kept_results(tmp_path)
    assert kept == [caught.value.kept] and is_result(kept[0])
    assert (kept[0] / "summary.json").is_file() and (kept[0] / "history.csv").is_file()
    assert str(kept[0]) in str(caught.value) and "notes.txt" in str(caught.value)
    no_debris(tmp_path)


def test_an_empty_folder_made_during_the_run_is_replaced(tmp_path):
    """An empty folder holds nothing to lose: the result takes its place (rename(2) puts a folder over
    an empty one only)."""
    import fem_impact

    out = tmp_path / "out"
    result = fem_impact.run(small_case(), out, progress=at_step(2, out.mkdir))
    assert result.outdir == out and (out / "summary.json").is_file()
    assert kept_results(tmp_path) == []
    no_debris(tmp_path)


def test_a_file_at_the_output_path_made_during_the_run_is_left(tmp_path):
    import fem_impact
    from fem_impact.app.outdir.policy import OutputFolderChanged

    out = tmp_path / "out"
    with pytest.raises(OutputFolderChanged, match="not a folder"):
        fem_impact.run(small_case(), out, progress=at_step(2, lambda: out.write_text("a file\n")))
    assert out.read_text() == "a file\n"
    assert len(kept_results(tmp_path)) == 1
    no_debris(tmp_path)


def test_a_folder_filled_between_the_check_and_the_move_is_not_replaced(tmp_path, monkeypatch):
    """The move itself: files that appear after the last check (here: just before the rename) make
    rename(2) fail; they are not replaced, and the result is kept beside them."""
    import fem_impact
    from fem_impact.app.outdir.policy import OutputFolderChanged

    out = tmp_path / "out"
    out.mkdir()
    real = os.rename

    def rename(src, dst, *args, **kwargs):
        if Path(dst) == out and ".partial-" in Path(src).name:
            (out / "thesis.tex").write_text("x\n")
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "rename", rename)
    with pytest.raises(OutputFolderChanged):
        fem_impact.run(small_case(), out)
    assert snapshot(out) == {"thesis.tex": b"x\n"}
    assert len(kept_results(tmp_path)) == 1
    no_debris(tmp_path)


HOOK = """
import shutil, sys
from pathlib import Path
import fem_impact.app.output as output

target, step = Path(sys.argv[1]), int(sys.argv[2])
write = output.HistoryWriter.write

def hooked(self, state):
    if state.step == step and not (target / "notes.txt").exists():   # the user, during the run
        shutil.rmtree(target, ignore_errors=True)
        target.mkdir()
        (target / "notes.txt").write_text("my notes\\n")
    write(self, state)

output.HistoryWriter.write = hooked
from fem_impact.app.cli import main
sys.exit(main(sys.argv[3:]))
"""


@pytest.mark.parametrize("command", ["run", "sweep", "reduction"])
def test_the_commands_say_where_the_result_went(tmp_path, command):
    """One line, status 2, the user's folder as they made it, the result beside it; for every command
    that stages its folder (the runs of a sweep or a reduction are inside its staging folder: the
    hook fires in the first of them)."""
    out = tmp_path / "out"
    args = {"run": ("run", CASES / "impacting_bar.yaml", "-q", *SMALL),
            "sweep": ("sweep", CASES / "impacting_bar.yaml", "--vary", "solver.dt=0.01,0.02", "-q", *SMALL[:2]),
            "reduction": ("reduction", CASES / "impacting_bar.yaml", "--modes", "2", *SMALL[:6])}[command]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-c", HOOK, out, "2", *args, "-o", out], capture_output=True,
                            text=True, env=env, timeout=300)
    kept = kept_results(tmp_path)
    refused(result, str(out), "not a fem-impact result", f"the results are in {kept[0]}")
    assert snapshot(out) == {"notes.txt": b"my notes\n"}
    assert len(kept) == 1 and (kept[0] / ".fem-impact.json").is_file()
    no_debris(tmp_path)


def test_a_picture_made_during_the_rendering_is_left(tmp_path, monkeypatch):
    """plot -o: the same check at the final replace of the picture."""
    import matplotlib.figure

    import fem_impact
    from fem_impact.app.outdir.policy import OutputFolderChanged
    from fem_impact.app.plots import plot_history

    out = fem_impact.run(small_case(), tmp_path / "run").outdir
    png = tmp_path / "fig.png"
    savefig = matplotlib.figure.Figure.savefig

    def hooked(self, *args, **kwargs):
        png.write_text("my own fig.png, not a picture\n")   # the user, during the rendering
        return savefig(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", hooked)
    with pytest.raises(OutputFolderChanged, match="is not a .png picture") as caught:
        plot_history(out, png)
    assert png.read_text() == "my own fig.png, not a picture\n"
    assert caught.value.kept.read_bytes().startswith(b"\x89PNG") and caught.value.kept.suffix == ".png"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["run", "fig.png", caught.value.kept.name])


# --- a write that fails: one line, status 3, nothing left, the earlier result untouched ---------

ENOSPC = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def full_disk_at(where: str, monkeypatch):
    """Make the run's writing fail as on a full disk at ``where`` (the errors a real one gives: a failed
    write names no file; dolfinx leaves a frame's file cut short and says nothing)."""
    from fem_impact.app import output
    from fem_impact.fem import dolfinx_api

    if where == "first VTK frame":
        monkeypatch.setattr(dolfinx_api, "_complete_xml", lambda path: False)
        full = types.SimpleNamespace(f_blocks=1000, f_bfree=0, f_bavail=0, f_frsize=4096)
        monkeypatch.setattr(dolfinx_api.os, "statvfs", lambda path: full)
    elif where == "history mid-run":
        init = output.HistoryWriter.__init__

        class FullDisk:
            def __init__(self, writer):
                self.writer, self.rows = writer, 0

            def writerow(self, row):
                self.writer.writerow(row)

            def writerows(self, rows):
                self.rows += 1
                if self.rows > 1:
                    raise ENOSPC
                self.writer.writerows(rows)

        def hooked(self, *args, **kwargs):
            init(self, *args, **{**kwargs, "flush_every": 2})
            if self._file:
                self._csv = FullDisk(self._csv)

        monkeypatch.setattr(output.HistoryWriter, "__init__", hooked)
    elif where == "summary":
        write_text = Path.write_text

        def hooked(self, *args, **kwargs):
            if self.name == "summary.json":
                raise ENOSPC
            return write_text(self, *args, **kwargs)

        monkeypatch.setattr(Path, "write_text", hooked)
    elif where == "move":
        rename = os.rename

        def hooked(src, dst, *args, **kwargs):
            if ".partial-" in Path(src).name:
                raise OSError(errno.EIO, os.strerror(errno.EIO), src, None, dst)
            return rename(src, dst, *args, **kwargs)

        monkeypatch.setattr(os, "rename", hooked)


WRITE_FAILURES = {"first VTK frame": ("out/results_p0_000000.vtu", "No space left on device"),
                  "history mid-run": ("out/history.csv", "No space left on device"),
                  "summary": ("out/summary.json", "No space left on device"),
                  "move": ("move the results into", "Input/output error")}


@pytest.mark.parametrize("where", list(WRITE_FAILURES))
def test_a_failed_write_leaves_the_earlier_result(tmp_path, monkeypatch, where):
    import fem_impact
    from fem_impact.app.outdir.writes import OutputWriteError

    out = tmp_path / "out"
    fem_impact.run(small_case(), out)
    before = snapshot(out)
    full_disk_at(where, monkeypatch)
    with pytest.raises(OutputWriteError) as caught:
        fem_impact.run(small_case(), out, force=True)   # (the size guard would see the full disk)
    name, reason = WRITE_FAILURES[where]
    assert str(caught.value).startswith("cannot ") and name in str(caught.value), caught.value
    assert str(caught.value).endswith(reason), caught.value
    assert snapshot(out) == before
    no_debris(tmp_path)


FULL_DISK_HOOK = """
import errno, os, sys
import fem_impact.app.output as output

class FullDisk:   # a csv writer on a full disk: the first rows fail (a failed write names no file)
    def writerows(self, rows):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

init = output.HistoryWriter.__init__

def hooked(self, *args, **kwargs):
    init(self, *args, **kwargs)
    self._csv = FullDisk()

output.HistoryWriter.__init__ = hooked
from fem_impact.app.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_failed_write_is_one_line_with_status_3(tmp_path):
    out = tmp_path / "out"
    assert cli("run", CASES / "impacting_bar.yaml", "-o", out, *SMALL, "-q").returncode == 0
    before = snapshot(out)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-c", FULL_DISK_HOOK, "run", CASES / "impacting_bar.yaml", "-o", out,
                             *SMALL, "-q"], capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 3, result.stderr
    # (history.csv is written out at the end, after the run's last checkpoint: kept, and said)
    kept = tmp_path / "out.checkpoint"
    assert result.stderr == (f"fem-impact: the run failed: cannot write {out / 'history.csv'}: No space left on "
                             f"device (the output folder was left as it was; the run's last checkpoint (t = 0.05) is "
                             f"kept in {kept}: continue it with --restart {kept})\n")
    assert snapshot(out) == before and (kept / "state.json").is_file()
    no_debris(tmp_path)


def in_small_filesystem(script: str, tmp_path: Path, size: str = "256k") -> subprocess.CompletedProcess:
    """``script`` (sh) with a small tmpfs (``size``) at tmp_path/disk, in a mount namespace of its own (nothing
    is mounted on this machine); skips where user namespaces are not allowed."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if shutil.which("unshare") is None:
        pytest.skip("no unshare")
    probe = subprocess.run(["unshare", "--map-root-user", "--mount", "true"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip("no user namespaces here")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(["unshare", "--map-root-user", "--mount", "sh", "-c",
                           f"mount -t tmpfs -o size={size} tmpfs {disk} && {script}"],
                          capture_output=True, text=True, env=env, timeout=300)


def test_a_really_full_disk(tmp_path):
    """No monkeypatching: a small file system fills up in the VTK frames (dolfinx says nothing: the
    frames are read back), then in history.csv; the earlier result stays, nothing is left behind."""
    out = tmp_path / "disk" / "out"
    run = f"{sys.executable} -m fem_impact run {CASES / 'impacting_bar.yaml'} -q --force -o {out}"
    result = in_small_filesystem(
        f"{run} {' '.join(SMALL)} && cd {out} && find . -type f -exec sha1sum {{}} + > {tmp_path / 'before.sha1'} && "
        f"cd / && "
        f"{run} --set solver.t_end=20; echo status $?; "
        f"{run} --set solver.t_end=20 --set output.every=100000; echo status $?; "
        f"cd {out} && sha1sum -c --quiet {tmp_path / 'before.sha1'} && echo same && ls -A {out.parent}", tmp_path)
    lines = result.stdout.split("\n") + result.stderr.split("\n")
    assert "status 3" in lines and lines.count("status 3") == 2, result
    assert f"fem-impact: the run failed: cannot write {out}/results_p0_" in result.stderr, result.stderr
    assert f"fem-impact: the run failed: cannot write {out}/history.csv: No space left on device (the output " \
           "folder was left as it was)" in result.stderr, result.stderr
    assert "Traceback" not in result.stderr
    assert result.stdout.split("\n")[-3:] == ["same", "out", ""], result.stdout


# --- a result folder holds what its command wrote, and the user's files (issue 30) ----------------

def manifest_of(folder: Path) -> list[str]:
    import json

    return json.loads((folder / ".fem-impact.json").read_text())["files"]


def test_a_rerun_over_files_of_the_user_refuses_and_keeps_them(tmp_path):
    """The issue's case: a notebook and a folder of figures put into a run's folder; the same run again
    refuses (one line, status 2, naming them) and leaves every file as it was."""
    out = tmp_path / "x"
    assert cli("run", CASES / "impacting_bar.yaml", "-o", out, *SMALL, "-q").returncode == 0
    (out / "analysis.ipynb").write_text("notes\n")
    (out / "figures").mkdir()
    (out / "figures" / "f.png").write_text("p\n")
    before = snapshot(out)
    again = cli("run", CASES / "impacting_bar.yaml", "-o", out, *SMALL, "--set", "solver.t_end=0.04", "-q")
    refused(again, str(out), "fem-impact did not write (analysis.ipynb, figures/)", "move them")
    assert snapshot(out) == before
    no_debris(tmp_path)


def users_entry(out: Path, where: str) -> Path:
    """A user's entry in the result ``out`` (returns what must stay as it was)."""
    if where == "nested in checkpoint/":
        (out / "checkpoint" / "why.txt").write_text("my note on this checkpoint\n")
    elif where == "hidden":
        (out / ".ipynb_checkpoints").mkdir()
        (out / ".ipynb_checkpoints" / "a.ipynb").write_text("{}\n")
    elif where == "a link to a folder elsewhere":
        data = out.parent / "data"
        data.mkdir()
        (data / "measurements.csv").write_text("t,x\n")
        os.symlink(data, out / "data")
    elif where == "a temporary file's name of another output":
        (out / ".summary.partial-4194303.txt").write_text("mine\n")
    elif where == "an earlier version's result (no manifest)":
        import json

        marker = json.loads((out / ".fem-impact.json").read_text())
        del marker["files"]
        (out / ".fem-impact.json").write_text(json.dumps(marker))
        (out / "thesis.tex").write_text("x\n")
    elif where == "an earlier version's result (no marker)":
        (out / ".fem-impact.json").unlink()
        (out / "thesis.tex").write_text("x\n")
    return out.parent


USERS_ENTRIES = {"nested in checkpoint/": "checkpoint/why.txt", "hidden": ".ipynb_checkpoints/",
                 "a link to a folder elsewhere": "data", "a temporary file's name of another output":
                 ".summary.partial-4194303.txt", "an earlier version's result (no manifest)": "thesis.tex",
                 "an earlier version's result (no marker)": "thesis.tex"}


@pytest.mark.parametrize("where", list(USERS_ENTRIES))
def test_a_result_holding_an_entry_of_the_user_is_refused(tmp_path, where):
    import fem_impact
    from fem_impact.errors import OutputFolderError

    out = tmp_path / "out"
    fem_impact.run(small_case(), out)
    users_entry(out, where)
    before = snapshot(tmp_path)
    with pytest.raises(OutputFolderError, match="the folder holds files fem-impact did not write") as caught:
        fem_impact.run(small_case(), out)
    assert f"({USERS_ENTRIES[where]})" in str(caught.value)
    assert snapshot(tmp_path) == before
    no_debris(tmp_path)


def test_the_manifest_lists_what_was_written_and_a_rerun_replaces_it(tmp_path):
    """The marker lists the run's files; a picture plot writes into the folder joins them (a rerun replaces
    it); a result of an earlier version holding its known files only is replaced too."""
    import json

    import fem_impact
    from fem_impact.app.outdir.manifest import tree
    from fem_impact.app.plots import plot_history

    out = tmp_path / "out"
    fem_impact.run(small_case(), out)
    files = manifest_of(out)
    assert files == tree(out) and {"history.csv", "summary.json", "checkpoint/", "checkpoint/state.json"} <= set(files)
    plot_history(out)
    assert manifest_of(out) == sorted([*files, "history.png"])
    fem_impact.run(small_case().with_changes({"solver.t_end": 0.04}), out)
    assert not (out / "history.png").exists() and manifest_of(out) == tree(out)
    marker = json.loads((out / ".fem-impact.json").read_text())
    del marker["files"]
    (out / ".fem-impact.json").write_text(json.dumps(marker))
    fem_impact.run(small_case(), out)
    assert manifest_of(out) == tree(out)
    no_debris(tmp_path)


def test_a_file_written_into_the_folder_during_the_rerun_is_kept(tmp_path):
    """Written while the rerun integrates: at the final move the folder is not the result it was; the file
    stays, the result goes beside it."""
    import fem_impact
    from fem_impact.app.outdir.manifest import is_result
    from fem_impact.app.outdir.policy import OutputFolderChanged

    out = tmp_path / "out"
    fem_impact.run(small_case(), out)
    with pytest.raises(OutputFolderChanged, match=r"did not write \(notes.txt\)") as caught:
        fem_impact.run(small_case(), out, progress=at_step(2, lambda: (out / "notes.txt").write_text("mine\n")))
    assert (out / "notes.txt").read_text() == "mine\n" and is_result(caught.value.kept)
    assert kept_results(tmp_path) == [caught.value.kept]
    no_debris(tmp_path)


def test_a_study_folder_holding_a_file_of_the_user_in_its_levels_is_refused(tmp_path):
    """A study's levels are its own (a study killed before it completes lists none of them); anything
    else under levels/ is the user's."""
    from fem_impact.app.outdir.manifest import write_marker_data
    from fem_impact.app.outdir.policy import check
    from fem_impact.errors import OutputFolderError

    study = tmp_path / "S"
    level = study / "levels" / "00-mesh.cells_10"
    level.mkdir(parents=True)
    write_marker_data(study, {"files": ["convergence.csv"]})
    (study / "convergence.csv").write_text("x\n")
    write_marker_data(level, {"files": ["history.csv"]})
    (level / "history.csv").write_text("x\n")
    (level / "level.json").write_text("{}\n")
    (study / "levels" / ".01-mesh.cells_20.partial-4194303").mkdir()   # a killed level run's staging folder
    assert check(study) == study
    (level / "plot.py").write_text("mine\n")
    (study / "levels" / "README").write_text("mine\n")
    with pytest.raises(OutputFolderError, match=r"did not write \(levels/00-mesh.cells_10/plot.py, levels/README\)"):
        check(study)


def test_a_failed_level_rerun_keeps_the_users_file(tmp_path):
    """A level that fails on a rerun replaces the earlier level's result by its record: the earlier run's
    files go, a file of the user's in the folder stays."""
    from fem_impact.app.outdir.manifest import write_marker_data
    from fem_impact.app.studies.levels import Level, Outcome, _record

    folder = tmp_path / "levels" / "00-a"
    folder.mkdir(parents=True)
    write_marker_data(folder, {"files": ["history.csv"]})
    (folder / "history.csv").write_text("x\n")
    (folder / "level.json").write_text("{}\n")
    (folder / "mine.txt").write_text("mine\n")
    _record(Outcome(Level("00-a", {}), "failed", "blew up", None, folder), "f")
    left = sorted(p.name for p in folder.iterdir())
    assert "history.csv" not in left and {"level.json", "mine.txt"} <= set(left)
    assert (folder / "mine.txt").read_text() == "mine\n"


def test_stale_debris_never_removes_a_users_file(tmp_path):
    """A rerun killed between its two moves: the earlier result (with a note of the user's) is aside in
    .NAME.old-PID. The next claim puts it back when the folder is missing; when the folder is there, it
    removes the earlier result's own files and puts the note back into the folder."""
    import fem_impact
    from fem_impact.app.outdir.claim import _remove_stale

    out = tmp_path / "out"
    fem_impact.run(small_case(), out)
    earlier = snapshot(out)
    aside = tmp_path / ".out.old-4194303"
    os.rename(out, aside)
    (aside / "note.txt").write_text("mine\n")
    _remove_stale(tmp_path, "out")
    assert not aside.exists() and snapshot(out) == {**earlier, "note.txt": b"mine\n"}
    shutil.copytree(out, aside)
    (out / "note.txt").unlink()
    _remove_stale(tmp_path, "out")
    assert not aside.exists() and (out / "note.txt").read_text() == "mine\n"
    assert snapshot(out) == {**earlier, "note.txt": b"mine\n"}


def test_size_guard_counts_the_checkpoints(monkeypatch):
    """Every run saves a checkpoint at its end (two on disk while the next one is written): the guard counts
    them, and names the mesh when they are the output's largest part."""
    from mpi4py import MPI

    from fem_impact.app import limits
    from fem_impact.config.case import CaseError, load_case

    case = load_case(CASES / "impacting_bar.yaml", ["mesh.cells=2000000", "output.vtk=false", "solver.t_end=0.001",
                                                    "solver.dt=1e-4"])
    est = limits.estimate(case)
    assert est.checkpoints == 2 * (limits.CHECKPOINT_BYTES_PER_DOF * 2000001 + limits.CHECKPOINT_BYTES_PER_RANK)
    assert est.output == est.history + est.vtk + est.checkpoints and est.checkpoints > 10 * est.history
    monkeypatch.setattr(limits, "free_disk", lambda folder: est.history + est.checkpoints / 2)
    with pytest.raises(CaseError, match=r"mesh.cells: the run would write about .*checkpoints 520 MB"):
        limits.check_limits(case, Path("/tmp/x"), MPI.COMM_SELF)


def test_a_full_disk_under_hdf5_is_one_line(tmp_path):
    """A small file system filled by an XDMF run (HDF5 printed its whole error stack, dozens of lines) and by
    a checkpoint (h5py's failed write, then its failed close: a traceback, a crash at exit): one line each,
    status 3, naming the file as it would be in the result (the series' data or its index, whichever filled the
    disk) and what the run kept (its last checkpoint). The XDMF
    run checkpoints at t = 1, 2, 3, ...: its series fills the disk between two (near t = 2.6), a checkpoint the
    other run."""
    out = tmp_path / "disk" / "out"
    run = f"{sys.executable} -m fem_impact run {CASES / 'impacting_bar.yaml'} -q --force -o {out}"
    result = in_small_filesystem(
        f"{run} --set output.format=xdmf --set solver.t_end=20 --set output.checkpoint_every=500; echo status $?; "
        f"rm -rf {out}.checkpoint; "
        f"{run} --set output.vtk=false --set mesh.cells=20000 --set solver.dt=1e-4 --set solver.t_end=0.01 "
        f"--set output.checkpoint_every=10; echo status $?; ls -A {out.parent}", tmp_path, size="2m")
    assert result.stdout.split("\n")[:2] == ["status 3", "status 3"], result
    first, second = result.stderr.splitlines()
    written = next((f for f in ("results.h5", "results.xdmf") if f"cannot write {out}/{f}:" in first), "results.h5")
    assert first.startswith(f"fem-impact: the run failed: cannot write {out}/{written}: No space left on device (the "
                            "output folder was left as it was; the run's last checkpoint (t = "), first
    assert first.endswith(f"is kept in {out}.checkpoint: continue it with --restart {out}.checkpoint)"), first
    assert second.startswith(f"fem-impact: the run failed: cannot write {out}/checkpoint/rank-0.h5: No space left on "
                             "device (the output folder was left as it was"), second
