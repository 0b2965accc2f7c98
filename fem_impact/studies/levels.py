"""Running the levels of a study: one run per level, each in its own folder ``OUTDIR/levels/NAME``.

- ``-j 1`` runs the levels one after the other in this process (after a one-step warm-up run,
  so that imports and form compilation are not timed); ``-j N`` runs N ``fem-impact run``
  processes at a time (their setup times then include the imports, and N runs share the cores:
  the CSV files say how many ran at once).
- Progress: one line per finished level on stderr, with the elapsed time and an estimate of the
  time left (from the steps of the levels still to run).
- Resume: each finished level leaves ``level.json`` (its overrides, status, reason and a
  fingerprint of the case file, the mesh file and the code that computes a run); a level whose
  folder holds a matching one is not run again.
- Failures: a run that raises SimulationError (blow-up, NaN) is a failed level with its message
  as the reason; without ``allow_failure`` the study stops (StudyStopped) once it is recorded.
  A run that refuses its input when it starts (CaseError, e.g. a method this version does not
  run) is a skipped level; a run that crashes (any other error) is a failed level with the error
  as the reason (and, in this process, its traceback logged as a warning). The run itself never
  writes a partial folder (run.staged_directory).
- Modes and static solves go to a cache private to the study run and deleted after it, so that
  the reduced model's timings include them (as on a first run of a scene).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..case import CaseError, load_case
from ..plots import history_columns

log = logging.getLogger(__name__)

LEVEL_FILE = "level.json"
PACKAGE = Path(__file__).resolve().parents[1]
# Modules that do not change what a run computes: editing them keeps completed levels valid.
_NOT_IN_FINGERPRINT = {"studies", "plots.py", "animate.py", "paraview_view.py", "cli.py", "references.py",
                       "__main__.py"}


@dataclass
class Level:
    """One run of a study: a folder name, the ``--set`` overrides, and what the study tabulates."""

    name: str
    overrides: tuple[str, ...]
    info: dict = field(default_factory=dict)
    label: str = ""

    def __post_init__(self):
        self.overrides = tuple(self.overrides)
        self.label = self.label or self.name


@dataclass
class Outcome:
    """What became of a level: ``status`` ok | failed | skipped, the reason, the run's summary."""

    level: Level
    status: str
    reason: str
    summary: dict | None
    folder: Path
    resumed: bool = False

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def history(self) -> dict[str, np.ndarray]:
        """history.csv as columns by their CSV names."""
        return history_columns(self.folder)


class StudyStopped(Exception):
    """A level failed and failures are not allowed: the study stops after recording it."""

    def __init__(self, outcome: Outcome):
        super().__init__(f"level {outcome.level.label} failed: {outcome.reason}")
        self.outcome = outcome


def slug(text: str) -> str:
    """A folder name from a label."""
    return re.sub(r"[^A-Za-z0-9._+-]+", "_", text).strip("_") or "level"


def code_fingerprint() -> str:
    """A hash of the package sources that decide what a run computes."""
    h = hashlib.sha256()
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        if rel.parts[0] in _NOT_IN_FINGERPRINT:
            continue
        h.update(str(rel).encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:20]


def _fingerprint(case_path: Path, case, code: str) -> str:
    h = hashlib.sha256(code.encode() + case_path.read_bytes())
    if case.mesh.file is not None:
        h.update(Path(case.mesh.file).read_bytes())
    return h.hexdigest()[:20]


def _steps(case) -> int:
    return max(1, int(np.ceil(case.solver.t_end / case.solver.dt - 1e-9)))


def _record(folder: Path, level: Level, fingerprint: str, status: str, reason: str) -> None:
    if status != "ok":   # a failed or refused run wrote nothing: its folder holds only the record
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
    data = {"overrides": list(level.overrides), "fingerprint": fingerprint, "status": status, "reason": reason,
            "info": level.info}
    tmp = folder / f".{LEVEL_FILE}.tmp"
    tmp.write_text(json.dumps(data, indent=2, default=str) + "\n")
    os.replace(tmp, folder / LEVEL_FILE)


def _resumable(folder: Path, level: Level, fingerprint: str) -> Outcome | None:
    try:
        data = json.loads((folder / LEVEL_FILE).read_text())
    except (OSError, ValueError):
        return None
    if data.get("overrides") != list(level.overrides) or data.get("fingerprint") != fingerprint:
        return None
    summary = None
    if data.get("status") == "ok":
        try:
            summary = json.loads((folder / "summary.json").read_text())
        except (OSError, ValueError):
            return None
        if not (folder / "history.csv").is_file():
            return None
    return Outcome(level, data.get("status", "failed"), data.get("reason", ""), summary, folder, resumed=True)


class _Progress:
    """One line per finished level: status, time, elapsed, and the time left estimated from steps."""

    def __init__(self, total: int, weights: dict[str, float], stream, quiet: bool, jobs: int):
        self.total, self.weights, self.stream, self.quiet, self.jobs = total, weights, stream, quiet, jobs
        self.done = 0
        self.t0 = time.perf_counter()
        self.run_weight = 0.0
        self.left_weight = sum(weights.values())

    def restart(self) -> None:
        """Start the clock (after the warm-up run)."""
        self.t0 = time.perf_counter()

    def __call__(self, outcome: Outcome) -> None:
        self.done += 1
        w = self.weights.get(outcome.level.name, 0.0)
        self.left_weight -= w
        if not outcome.resumed:
            self.run_weight += w
        if self.quiet:
            return
        elapsed = time.perf_counter() - self.t0
        if outcome.resumed:
            what = f"kept from an earlier run ({outcome.status})"
        elif outcome.ok:
            what = f"ok, {outcome.summary['steps']} steps, loop {outcome.summary['loop_time_s']:.2f} s"
        else:
            what = f"{outcome.status.upper()}: {outcome.reason}"
        eta = elapsed * self.left_weight / self.run_weight if self.run_weight > 0 else 0.0
        width = len(str(self.total))
        self.stream.write(f"[{self.done:>{width}}/{self.total}] {outcome.level.label}: {what} "
                          f"(elapsed {elapsed:.1f} s, about {eta:.0f} s left)\n")
        self.stream.flush()


def run_levels(case_path, levels: list[Level], outdir, jobs: int = 1, allow_failure: bool = False,
               stream=None, quiet: bool = False) -> list[Outcome]:
    """Run (or resume) ``levels`` of the case into ``outdir/levels``; returns their outcomes in order.

    Every level's overrides are validated first (CaseError before anything is written).
    Raises StudyStopped when a level fails and ``allow_failure`` is false.
    """
    case_path = Path(os.path.abspath(case_path))
    stream = stream or sys.stderr
    names = [lv.name for lv in levels]
    if len(set(names)) != len(names):
        raise ValueError(f"level names must be unique: {names}")
    cases = {lv.name: load_case(case_path, lv.overrides) for lv in levels}   # CaseError: nothing written
    code = code_fingerprint()
    prints = {name: _fingerprint(case_path, case, code) for name, case in cases.items()}
    root = Path(outdir) / "levels"
    outcomes: dict[str, Outcome] = {}
    todo = []
    for lv in levels:
        kept = _resumable(root / lv.name, lv, prints[lv.name])
        if kept is not None:
            outcomes[lv.name] = kept
        else:
            todo.append(lv)
    progress = _Progress(len(levels), {n: float(_steps(c)) for n, c in cases.items()}, stream, quiet, jobs)
    for lv in levels:
        if lv.name in outcomes:
            progress(outcomes[lv.name])
    if todo:
        root.mkdir(parents=True, exist_ok=True)
        cache = Path(tempfile.mkdtemp(prefix=".cache-", dir=outdir))
        try:
            runner = _run_in_process if jobs <= 1 else _run_in_processes
            runner(case_path, todo, root, prints, cases, jobs, allow_failure, progress, outcomes, cache)
        finally:
            shutil.rmtree(cache, ignore_errors=True)
    return [outcomes[lv.name] for lv in levels]


def _finish(outcome: Outcome, prints, progress, outcomes, allow_failure) -> None:
    lv = outcome.level
    _record(outcome.folder, lv, prints[lv.name], outcome.status, outcome.reason)
    outcomes[lv.name] = outcome
    progress(outcome)
    if outcome.status == "failed" and not allow_failure:
        raise StudyStopped(outcome)


# --- in this process ---------------------------------------------------------------------------


def _run_in_process(case_path, todo, root, prints, cases, jobs, allow_failure, progress, outcomes, cache):
    from mpi4py import MPI

    from ..errors import SimulationError
    from ..pipeline import run_case

    saved = os.environ.get("FEM_IMPACT_CACHE")
    os.environ["FEM_IMPACT_CACHE"] = str(cache)
    try:
        _warm_up(case_path, todo, cases, cache)
        progress.restart()
        for lv in todo:
            folder = root / lv.name
            try:
                with warnings.catch_warnings():   # (overflow on the way to a blow-up: the run reports it)
                    warnings.simplefilter("ignore", RuntimeWarning)
                    run_case(case_path, folder, list(lv.overrides), comm=MPI.COMM_SELF, progress=False)
                # (the summary as written, as a resumed or parallel level reads it)
                outcome = Outcome(lv, "ok", "", json.loads((folder / "summary.json").read_text()), folder)
            except SimulationError as err:
                outcome = Outcome(lv, "failed", _one_line(str(err)), None, folder)
            except CaseError as err:
                outcome = Outcome(lv, "skipped", _one_line(str(err)), None, folder)
            except Exception as err:   # a crash of the run: recorded like a failure (as a process's would be)
                log.warning("level %s crashed", lv.label, exc_info=True)
                outcome = Outcome(lv, "failed", _one_line(f"the run crashed: {type(err).__name__}: {err}"), None,
                                  folder)
            _finish(outcome, prints, progress, outcomes, allow_failure)
    finally:
        if saved is None:
            os.environ.pop("FEM_IMPACT_CACHE", None)
        else:
            os.environ["FEM_IMPACT_CACHE"] = saved


def _warm_up(case_path, todo, cases, cache) -> None:
    """One step of the first level (full model), so that imports and form compilation are not timed."""
    from mpi4py import MPI

    from ..errors import SimulationError
    from ..pipeline import run_case

    if any(c.solver.method == "modal" for c in cases.values()):
        from .. import modes  # noqa: F401  (SLEPc)
    first = todo[0]
    dt = cases[first.name].solver.dt
    try:
        run_case(case_path, cache / "warm-up", [*first.overrides, "solver.method=newmark", f"solver.t_end={dt!r}",
                                                "output.vtk=false"], comm=MPI.COMM_SELF, progress=False)
    except (CaseError, SimulationError):
        pass   # the level itself will say what is wrong
    shutil.rmtree(cache / "warm-up", ignore_errors=True)


def _one_line(text: str) -> str:
    return " ".join(text.split())


# --- in parallel processes -----------------------------------------------------------------------

_RUN_FAILED = "fem-impact: the run failed: "
_LEFT_AS_IT_WAS = " (the output folder was left as it was)"
_BAD_INPUT = "fem-impact: error: "


def _command(case_path: Path, folder: Path, overrides) -> list[str]:
    args = [sys.executable, "-m", "fem_impact", "run", str(case_path), "-o", str(folder), "-q"]
    for option in overrides:
        args += ["--set", option]
    return args


def _from_process(lv: Level, folder: Path, status: int, stderr: str) -> Outcome:
    lines = [line for line in stderr.strip().splitlines() if line.strip()]
    last = lines[-1] if lines else ""
    if status == 0:
        return Outcome(lv, "ok", "", json.loads((folder / "summary.json").read_text()), folder)
    if status == 3 and last.startswith(_RUN_FAILED):
        return Outcome(lv, "failed", last[len(_RUN_FAILED):].removesuffix(_LEFT_AS_IT_WAS), None, folder)
    if status == 2 and last.startswith(_BAD_INPUT):
        return Outcome(lv, "skipped", last[len(_BAD_INPUT):], None, folder)
    how = f"killed by signal {-status}" if status < 0 else f"exited with status {status}"
    return Outcome(lv, "failed", f"the run {how}: {last}" if last else f"the run {how}", None, folder)


def _run_in_processes(case_path, todo, root, prints, cases, jobs, allow_failure, progress, outcomes, cache):
    env = dict(os.environ, FEM_IMPACT_CACHE=str(cache), OPENBLAS_NUM_THREADS="1")
    # The children import this very package, wherever it was imported from.
    env["PYTHONPATH"] = os.pathsep.join([str(PACKAGE.parent), *filter(None, [os.environ.get("PYTHONPATH")])])
    running: dict[str, subprocess.Popen] = {}
    lock = threading.Lock()
    stopping = threading.Event()

    def work(lv: Level):
        if stopping.is_set():
            return None
        folder = root / lv.name
        proc = subprocess.Popen(_command(case_path, folder, lv.overrides), stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True, env=env)
        with lock:
            running[lv.name] = proc
        _, stderr = proc.communicate()
        with lock:
            running.pop(lv.name, None)
        if stopping.is_set():
            return None
        return _from_process(lv, folder, proc.returncode, stderr)

    def stop_children():
        stopping.set()
        with lock:
            procs = list(running.values())
        for proc in procs:   # SIGINT: the run removes its staging folder and exits
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()

    pool = ThreadPoolExecutor(max_workers=jobs)
    futures = {pool.submit(work, lv) for lv in todo}
    try:
        while futures:
            done, futures = wait(futures, return_when=FIRST_COMPLETED)
            for fut in done:
                outcome = fut.result()
                if outcome is not None:
                    _finish(outcome, prints, progress, outcomes, allow_failure)
    except BaseException:
        for fut in futures:
            fut.cancel()
        stop_children()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
