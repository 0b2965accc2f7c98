"""Running the levels of a study: one run per level, each in its own folder ``OUTDIR/levels/NAME``.

A level is a copy of the study's case with changes (dotted key paths to values, ``Case.with_changes``);
each is run from its data by :func:`.worker.run_data` (:func:`fem_impact.run`), which reports a status: ok,
failed or skipped, the reason, the error's type and the run's summary.

- ``-j 1`` runs the levels one after the other in this process (after a one-step warm-up run,
  so that imports and form compilation are not timed); ``-j N`` runs N child processes at a time
  (``python -m fem_impact.app.studies.worker``: the level's case as data in, its status as JSON out;
  their setup times then include the imports, and N runs share the cores: the CSV files say how
  many ran at once).
- Progress: one line per finished level on stderr, with the elapsed time and an estimate of the
  time left (from the steps of the levels still to run).
- Resume: each finished level leaves ``level.json`` (its changes, status, reason and a
  fingerprint of the resolved case, the mesh file and the code that computes a run); a level whose
  folder holds a matching one is not run again.
- Failures: a run that raises SimulationError (blow-up, NaN) is a failed level with its message
  as the reason; without ``allow_failure`` the study stops (StudyStopped) once it is recorded.
  A run that refuses its input when it starts (CaseError, e.g. a method this version does not
  run) is a skipped level; a run that crashes (any other error) is a failed level with the error
  as the reason (and its traceback logged as a warning). The run itself never writes a partial
  folder (pipeline.staged_directory); Ctrl-C stops the children, which remove their staging folders.
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
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...cache import code_fingerprint
from ...config.case import Case
from ...integrators.parameters import steps_for
from ..outdir.manifest import remove_result
from ..outdir.writes import replacing
from ..plots import history_columns
from ..progress import duration
from . import worker

log = logging.getLogger(__name__)

LEVEL_FILE = "level.json"
PACKAGE = Path(__file__).resolve().parents[1]


@dataclass
class Level:
    """One run of a study: a folder name, the changes to the study's case, and what the study tabulates."""

    name: str
    changes: dict
    info: dict = field(default_factory=dict)
    label: str = ""

    def __post_init__(self):
        self.changes = dict(self.changes)
        self.label = self.label or self.name


@dataclass
class Outcome:
    """What became of a level: ``status`` ok | failed | skipped, the reason, the run's summary,
    and the level's case (the study's case with the level's changes)."""

    level: Level
    status: str
    reason: str
    summary: dict | None
    folder: Path
    case: Case | None = None
    resumed: bool = False
    error: str | None = None   # the type of the error a failed or skipped run raised

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


def fingerprint(case: Case, code: str) -> str:
    """What decides a level's run: the resolved case, the mesh file's bytes and the code."""
    h = hashlib.sha256(code.encode())
    h.update(json.dumps(case.resolved(), sort_keys=True, default=str).encode())
    if case.mesh.file is not None:
        h.update(Path(case.mesh.file).read_bytes())
    return h.hexdigest()[:20]


def _record(outcome: Outcome, fingerprint: str) -> None:
    folder = outcome.folder
    if outcome.status != "ok":   # a failed or refused run wrote nothing: its folder holds only the record
        if folder.exists():   # (an earlier run's result: what fem-impact wrote in it, never a file of the user's)
            remove_result(folder, level=True)
        folder.mkdir(parents=True, exist_ok=True)
    data = {"changes": outcome.level.changes, "fingerprint": fingerprint, "status": outcome.status,
            "reason": outcome.reason, "error": outcome.error, "info": outcome.level.info}
    with replacing(folder / LEVEL_FILE) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=str) + "\n")


def _resumable(folder: Path, level: Level, case: Case, fingerprint: str) -> Outcome | None:
    try:
        data = json.loads((folder / LEVEL_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("fingerprint") != fingerprint:
        return None
    summary = None
    if data.get("status") == "ok":
        try:
            summary = json.loads((folder / "summary.json").read_text())
        except (OSError, ValueError):
            return None
        if not (folder / "history.csv").is_file():
            return None
    return Outcome(level, data.get("status", "failed"), data.get("reason", ""), summary, folder, case,
                   resumed=True, error=data.get("error"))


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
                          f"(elapsed {duration(elapsed)}, about {duration(eta)} left)\n")
        self.stream.flush()


def run_levels(case: Case, levels: list[Level], outdir, jobs: int = 1, allow_failure: bool = False,
               stream=None, quiet: bool = False) -> list[Outcome]:
    """Run (or resume) ``levels`` of ``case`` into ``outdir/levels``; returns their outcomes in order.

    Every level's changes are validated first (CaseError before anything is written).
    Raises StudyStopped when a level fails and ``allow_failure`` is false.
    """
    stream = stream or sys.stderr
    names = [lv.name for lv in levels]
    if len(set(names)) != len(names):
        raise ValueError(f"level names must be unique: {names}")
    cases = {lv.name: case.with_changes(lv.changes) for lv in levels}   # CaseError: nothing written
    code = code_fingerprint()
    prints = {name: fingerprint(c, code) for name, c in cases.items()}
    root = Path(outdir) / "levels"
    outcomes: dict[str, Outcome] = {}
    todo = []
    for lv in levels:
        kept = _resumable(root / lv.name, lv, cases[lv.name], prints[lv.name])
        if kept is not None:
            outcomes[lv.name] = kept
        else:
            todo.append(lv)
    steps = {n: float(steps_for(c.solver.t_end, c.solver.dt)) for n, c in cases.items()}
    progress = _Progress(len(levels), steps, stream, quiet, jobs)
    for lv in levels:
        if lv.name in outcomes:
            progress(outcomes[lv.name])
    if todo:
        root.mkdir(parents=True, exist_ok=True)
        cache = Path(tempfile.mkdtemp(prefix=".cache-", dir=outdir))
        try:
            runner = _run_in_process if jobs <= 1 else _run_in_processes
            runner(todo, root, prints, cases, jobs, allow_failure, progress, outcomes, cache)
        finally:
            shutil.rmtree(cache, ignore_errors=True)
    return [outcomes[lv.name] for lv in levels]


def _outcome(lv: Level, folder: Path, case: Case, status: dict) -> Outcome:
    """A level's outcome from its run's status (:func:`.worker.run_data`); a crash's traceback is logged."""
    if status.get("traceback"):
        log.warning("level %s crashed:\n%s", lv.label, status["traceback"].rstrip())
    return Outcome(lv, status["status"], status["reason"], status["summary"] if status["status"] == "ok" else None,
                   folder, case, error=status.get("error"))


def _finish(outcome: Outcome, prints, progress, outcomes, allow_failure) -> None:
    lv = outcome.level
    _record(outcome, prints[lv.name])
    outcomes[lv.name] = outcome
    progress(outcome)
    if outcome.status == "failed" and not allow_failure:
        raise StudyStopped(outcome)


# --- in this process ---------------------------------------------------------------------------


def _run_in_process(todo, root, prints, cases, jobs, allow_failure, progress, outcomes, cache):
    saved = os.environ.get("FEM_IMPACT_CACHE")
    os.environ["FEM_IMPACT_CACHE"] = str(cache)
    try:
        _warm_up(cases[todo[0].name], cases, cache)
        progress.restart()
        for lv in todo:
            folder = root / lv.name
            case = cases[lv.name]   # (run from its data, as a child runs it)
            outcome = _outcome(lv, folder, case, worker.run_data(case.resolved(), case.base_dir, folder))
            _finish(outcome, prints, progress, outcomes, allow_failure)
    finally:
        if saved is None:
            os.environ.pop("FEM_IMPACT_CACHE", None)
        else:
            os.environ["FEM_IMPACT_CACHE"] = saved


def _warm_up(first: Case, cases, cache) -> None:
    """One step of the first level (full model), so that imports and form compilation are not timed."""
    from mpi4py import MPI

    from ...errors import CaseError, SimulationError
    from ..pipeline import run

    from ...integrators import DEFAULT_METHOD, is_reduced

    if any(is_reduced(c.solver) for c in cases.values()):
        from ...fem import modes  # noqa: F401  (SLEPc)
    try:
        warm = first.with_changes({"solver.method": DEFAULT_METHOD, "solver.t_end": first.solver.dt,
                                   "output.vtk": False})
        run(warm, cache / "warm-up", comm=MPI.COMM_SELF, progress=False)
    except (CaseError, SimulationError):
        pass   # the level itself will say what is wrong
    shutil.rmtree(cache / "warm-up", ignore_errors=True)


# --- in parallel processes -----------------------------------------------------------------------


def _command(spec: Path) -> list[str]:
    return [sys.executable, "-m", "fem_impact.app.studies.worker", str(spec)]


def _from_child(lv: Level, folder: Path, case: Case, returncode: int, status_file: Path, log_file: Path) -> Outcome:
    """The outcome the child reported; a child that reported none (killed, or dead before it could) failed."""
    status = worker.read_status(status_file)
    if status is not None:
        return _outcome(lv, folder, case, status)
    how = f"killed by signal {-returncode}" if returncode < 0 else f"exited with status {returncode}"
    try:   # what it said, for the user (the outcome does not depend on it)
        said = log_file.read_text(errors="replace").strip()
    except OSError:
        said = ""
    if returncode == worker.WRITE_FAILED:   # it could not write its results: not the level's outcome, the study's
        from ..outdir.writes import OutputWriteError

        raise OutputWriteError(said.splitlines()[-1] if said else f"level {lv.label}: cannot write its results")
    if said:
        log.warning("level %s: the run %s; it wrote:\n%s", lv.label, how, "\n".join(said.splitlines()[-20:]))
    return Outcome(lv, "failed", f"the run {how} without reporting its status", None, folder, case)


def _run_in_processes(todo, root, prints, cases, jobs, allow_failure, progress, outcomes, cache):
    env = dict(os.environ, FEM_IMPACT_CACHE=str(cache), OPENBLAS_NUM_THREADS="1")
    # The children import this very package, wherever it was imported from.
    env["PYTHONPATH"] = os.pathsep.join([str(PACKAGE.parent), *filter(None, [os.environ.get("PYTHONPATH")])])
    work_dir = cache / "jobs"   # the children's specs, statuses and stderr
    work_dir.mkdir()
    running: dict[str, subprocess.Popen] = {}
    lock = threading.Lock()
    stopping = threading.Event()

    def work(lv: Level):
        if stopping.is_set():
            return None
        folder, case = root / lv.name, cases[lv.name]
        status_file, log_file = work_dir / f"{lv.name}.status.json", work_dir / f"{lv.name}.log"
        spec = worker.write_spec(work_dir / f"{lv.name}.json", case, folder, status_file)
        with open(log_file, "w") as stderr:
            proc = subprocess.Popen(_command(spec), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                    stderr=stderr, env=env)
            with lock:
                running[lv.name] = proc
                if stopping.is_set():   # (stop_children looked before this child was registered)
                    proc.send_signal(signal.SIGINT)
            proc.wait()
        with lock:
            running.pop(lv.name, None)
        if stopping.is_set():
            return None
        return _from_child(lv, folder, case, proc.returncode, status_file, log_file)

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
