"""The probe harness: scripted fault probes of fem-impact as a user meets it, counted by class.

A probe does what a user might (a damaged checkpoint, a changed case on restart, a signal under
MPI, a file of their own in a result folder) through the real command line, and judges the
outcome. Each probe ends in one verdict:

- ``ok``: what the tool promises (a refusal in one plain line with status 2, a correct result);
- ``traceback``: a Python traceback, or a crash (a signal ended the interpreter);
- ``hang``: still running at its time limit (killed, with its process group);
- ``lost``: a file the program did not write was changed or removed;
- ``wrong``: a silent wrong answer (status 0, or a message, where the probe knows the physics or the
  contract says otherwise);
- ``error``: the probe itself failed (a defect of the probe: counted, never hidden).

    python -m tools.probes                 # every class, two probes at a time; a table of counts
    python -m tools.probes -k restart -v   # the classes whose name holds "restart", each verdict

A class is a module of this folder that defines probes with :func:`probe`; a new feature adds its
module (and so its class) here. ``tests/test_probes.py`` runs every class in the slow tier and
requires zero of every verdict but ``ok``.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import os
import pkgutil
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CASES = ROOT / "cases"
VERDICTS = ("ok", "traceback", "hang", "lost", "wrong", "error")
BAD = VERDICTS[1:]


@dataclass
class Verdict:
    kind: str
    detail: str = ""

    def __post_init__(self):
        if self.kind not in VERDICTS:
            raise ValueError(f"unknown verdict {self.kind!r}")


def ok(detail: str = "") -> Verdict:
    return Verdict("ok", detail)


def wrong(detail: str) -> Verdict:
    return Verdict("wrong", detail)


def lost(detail: str) -> Verdict:
    return Verdict("lost", detail)


@dataclass
class Probe:
    cls: str
    name: str
    body: Callable[[Context], Verdict]
    timeout: float = 180.0   # a hang is any command of the probe still running after this long


PROBES: list[Probe] = []


def run_case(ctx, data: dict, *options, mpi: int = 0, out: str = "out"):
    """Write the case ``data`` into the probe's folder and run it into ``out`` there: (completed, folder)."""
    import yaml

    case = ctx.folder / f"{data['name']}.yaml"
    case.write_text(yaml.safe_dump(data, sort_keys=False))
    folder = ctx.folder / out
    return ctx.run("run", case, "-q", "-o", folder, *options, mpi=mpi), folder


def history(out) -> dict:
    """A run's history.csv as columns by name."""
    import csv

    import numpy as np

    with open(Path(out) / "history.csv", newline="") as f:
        rows = list(csv.reader(f))
    values = np.array(rows[1:], dtype=float)
    return {name: values[:, k] for k, name in enumerate(rows[0])}


def solved(ctx, data: dict, *options, mpi: int = 0, out: str = "out"):
    """(the run's history, None), or (None, the verdict of a run that did not end cleanly)."""
    r, folder = run_case(ctx, data, *options, mpi=mpi, out=out)
    bad = ctx.succeeded(r)
    return (None, bad) if bad else (history(folder), None)


def restart_parts(ctx, data: dict, t_split: float, t_end: float):
    """A run of ``data`` to ``t_split`` continued to ``t_end`` with --restart, against the run straight to
    ``t_end``: (None, the largest difference of a history column), or (the verdict of a run that failed, None)."""
    import numpy as np

    data["solver"]["t_end"] = t_split
    _, bad = solved(ctx, data, out="first")
    if bad:
        return bad, None
    data["solver"]["t_end"] = t_end
    whole, bad = solved(ctx, data, out="whole")
    if bad:
        return bad, None
    continued, bad = solved(ctx, data, "--restart", ctx.folder / "first", out="continued")
    if bad:
        return bad, None
    n = continued["t"].size
    return None, max(np.abs(whole[k][-n:] - continued[k]).max() for k in continued)


def probe(cls: str, name: str, timeout: float = 180.0):
    """Register the decorated ``body(ctx) -> Verdict`` as a probe of class ``cls``."""
    def register(body):
        PROBES.append(Probe(cls, name, body, timeout))
        return body
    return register


@dataclass
class Completed:
    args: list
    status: int | None   # None: killed at the time limit
    stdout: str
    stderr: str
    seconds: float

    @property
    def hung(self) -> bool:
        return self.status is None

    @property
    def traceback(self) -> bool:
        """A Python traceback on either stream, or an interpreter ended by a signal other than the probe's."""
        text = self.stdout + self.stderr
        return "Traceback (most recent call last)" in text or (self.status is not None and self.status < 0) \
            or "Segmentation fault" in text or "MPI_ABORT" in text and "Traceback" in text

    def lines(self) -> list[str]:
        return [line for line in self.stderr.splitlines() if line.strip()]

    def tail(self, n: int = 3) -> str:
        text = (self.stderr.strip() or self.stdout.strip()).splitlines()
        return " | ".join(text[-n:])[:400]


class _Hung(Exception):
    def __init__(self, completed: Completed):
        self.completed = completed



def default_signals() -> None:
    """A probed command starts with the default dispositions, also when the harness itself was started with
    SIGHUP, SIGINT or SIGQUIT ignored (nohup; a shell's background job ignores SIGINT and SIGQUIT): else it
    would rightly go on after them."""
    for sig in (signal.SIGHUP, signal.SIGINT, signal.SIGQUIT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)

class Context:
    """What a probe works with: a folder of its own, the command line, snapshots of user files."""

    def __init__(self, folder: Path, timeout: float, shared: Shared):
        self.folder, self.timeout, self._shared = folder, timeout, shared
        self._kept: dict[Path, dict[str, str]] = {}

    # -- the command line ---------------------------------------------------------------------
    def command(self, *args, mpi: int = 0) -> list[str]:
        base = [sys.executable, "-m", "fem_impact", *map(str, args)]
        if mpi:
            return ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", str(mpi), *base]
        return base

    def run(self, *args, mpi: int = 0, timeout: float | None = None, cwd=None, env=None,
            signal_at: tuple[float | Callable[[], bool], int] | None = None, python: bool = False) -> Completed:
        """``fem-impact ARGS`` (or ``python ARGS`` with ``python=True``), in its own process group.

        ``signal_at=(when, SIG)``: send SIG to the process (mpirun under MPI) once ``when`` seconds have
        passed, or once the callable ``when()`` is true (SIG 0: nothing more, the callable signals itself). A command still running at the time limit is
        killed with its group and raises, ending the probe as a hang.
        """
        cmd = [sys.executable, *map(str, args)] if python else self.command(*args, mpi=mpi)
        limit = timeout or self.timeout
        environ = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
                   **(env or {})}
        environ.pop("PYTEST_CURRENT_TEST", None)
        start = time.monotonic()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=cwd or self.folder, env=environ, start_new_session=True,
                                preexec_fn=default_signals)
        if signal_at is not None:
            when, sig = signal_at

            def send():
                while proc.poll() is None and time.monotonic() - start < limit:
                    if (when() if callable(when) else time.monotonic() - start >= when):
                        with contextlib.suppress(ProcessLookupError):
                            proc.send_signal(sig)
                        return
                    time.sleep(0.02)

            threading.Thread(target=send, daemon=True).start()
        try:
            out, err = proc.communicate(timeout=limit)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
            raise _Hung(Completed(cmd, None, out, err, time.monotonic() - start)) from None
        status = proc.returncode
        if signal_at is not None and signal_at[1] and status == -signal_at[1]:
            status = 128 + signal_at[1]   # (ended by the probe's own signal: not a crash)
        return Completed(cmd, status, out, err, time.monotonic() - start)

    # -- judging ------------------------------------------------------------------------------
    def refused(self, r: Completed, *needles: str, status: int = 2, max_lines: int = 6) -> Verdict:
        """The contract for bad input: status 2 (or ``status``), a few plain lines naming ``needles``."""
        if r.traceback:
            return Verdict("traceback", r.tail())
        if r.status == 0:
            return wrong(f"accepted (status 0): {r.tail()}")
        if r.status != status:
            return wrong(f"status {r.status}, expected {status}: {r.tail()}")
        text = r.stderr
        missing = [n for n in needles if n.lower() not in text.lower()]
        if missing:
            return wrong(f"the message does not name {missing}: {r.tail()}")
        if len(r.lines()) > max_lines:
            return wrong(f"{len(r.lines())} lines on stderr: {r.tail()}")
        return ok(r.tail(1))

    def succeeded(self, r: Completed) -> Verdict | None:
        """None when ``r`` ran cleanly (status 0, no traceback); else its verdict."""
        if r.traceback:
            return Verdict("traceback", r.tail())
        if r.status != 0:
            return wrong(f"status {r.status}: {r.tail()}")
        return None

    # -- user files ---------------------------------------------------------------------------
    def keep(self, folder) -> None:
        """Remember every file under ``folder``, or the file ``folder`` (a user's, which no command may change
        or remove)."""
        folder = Path(folder)
        if folder.is_file():
            self._kept[folder] = {"": _digest(folder)}
            return
        self._kept[folder] = {str(p.relative_to(folder)): _digest(p) for p in folder.rglob("*") if p.is_file()}

    def lost_files(self) -> list[str]:
        missing = []
        for folder, files in self._kept.items():
            for name, digest in files.items():
                p = folder / name if name else folder
                if not p.is_file() or _digest(p) != digest:
                    missing.append(str(p))
        return missing

    # -- shared, expensive inputs ------------------------------------------------------------
    def shared(self, key: str, build: Callable[[Path], None]) -> Path:
        """A copy, in this probe's folder, of what ``build(folder)`` made once for every probe (a run, a
        checkpoint): probes may damage their copy freely."""
        source = self._shared.get(key, build)
        target = self.folder / key
        shutil.copytree(source, target, symlinks=True)
        return target


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class Shared:
    """Inputs built once per harness run (under a lock each), in a folder of the run."""

    def __init__(self, folder: Path):
        self.folder = folder
        self._locks: dict[str, threading.Lock] = {}
        self._guard = threading.Lock()
        self._failed: dict[str, str] = {}

    def get(self, key: str, build: Callable[[Path], None]) -> Path:
        with self._guard:
            lock = self._locks.setdefault(key, threading.Lock())
        with lock:
            target = self.folder / key
            if key in self._failed:
                raise RuntimeError(f"shared input {key} could not be built: {self._failed[key]}")
            if not target.exists():
                work = self.folder / f".{key}.build"
                shutil.rmtree(work, ignore_errors=True)
                work.mkdir(parents=True)
                try:
                    build(work)
                except Exception as err:
                    self._failed[key] = f"{type(err).__name__}: {err}"
                    raise
                work.rename(target)
            return target


def load(pattern: str | None = None) -> list[Probe]:
    """Import every class module of this folder; the probes whose class holds ``pattern``."""
    for info in pkgutil.iter_modules([str(Path(__file__).parent)]):
        if not info.name.startswith("_"):
            importlib.import_module(f"{__name__}.{info.name}")
    return [p for p in PROBES if pattern is None or pattern in p.cls]


@dataclass
class Report:
    results: list[tuple[Probe, Verdict, float]] = field(default_factory=list)

    def counts(self) -> dict[str, dict[str, int]]:
        table: dict[str, dict[str, int]] = {}
        for p, v, _ in self.results:
            row = table.setdefault(p.cls, dict.fromkeys(VERDICTS, 0))
            row[v.kind] += 1
        return dict(sorted(table.items()))

    def failures(self) -> list[tuple[Probe, Verdict, float]]:
        return [r for r in self.results if r[1].kind != "ok"]

    def table(self) -> str:
        counts = self.counts()
        width = max([len("class"), *map(len, counts)])
        lines = [f"{'class':<{width}}  {'probes':>6}  " + "  ".join(f"{v:>9}" for v in VERDICTS)]
        total = dict.fromkeys(VERDICTS, 0)
        for cls, row in counts.items():
            lines.append(f"{cls:<{width}}  {sum(row.values()):>6}  " + "  ".join(f"{row[v]:>9}" for v in VERDICTS))
            for v in VERDICTS:
                total[v] += row[v]
        lines.append(f"{'all':<{width}}  {sum(total.values()):>6}  " + "  ".join(f"{total[v]:>9}" for v in VERDICTS))
        return "\n".join(lines)


def run_probes(probes: list[Probe], workers: int = 2, folder: Path | None = None,
               report: Callable[[Probe, Verdict, float], None] | None = None) -> Report:
    """Run ``probes``, ``workers`` at a time, each in a folder of its own; returns their verdicts."""
    from concurrent.futures import ThreadPoolExecutor

    own = folder is None
    base = Path(tempfile.mkdtemp(prefix="fem-impact-probes-")) if own else Path(folder)
    shared = Shared(base / "shared")
    shared.folder.mkdir(parents=True, exist_ok=True)
    out = Report()
    lock = threading.Lock()

    def one(index_probe):
        index, p = index_probe
        where = base / f"{index:04d}"
        where.mkdir(parents=True, exist_ok=True)
        ctx = Context(where, p.timeout, shared)
        start = time.monotonic()
        try:
            verdict = p.body(ctx)
            if not isinstance(verdict, Verdict):
                verdict = Verdict("error", f"the probe returned {verdict!r}, not a Verdict")
            gone = ctx.lost_files()
            if gone and verdict.kind in ("ok", "wrong"):
                verdict = lost(f"{len(gone)} user file(s) changed or removed: {gone[:3]}")
        except _Hung as hung:
            verdict = Verdict("hang", f"{' '.join(map(str, hung.completed.args[-6:]))} still running after "
                                      f"{hung.completed.seconds:.0f} s: {hung.completed.tail()}")
        except Exception as err:   # the probe's own defect: counted, never hidden
            verdict = Verdict("error", f"{type(err).__name__}: {err}")
        seconds = time.monotonic() - start
        with lock:
            out.results.append((p, verdict, seconds))
            if report is not None:
                report(p, verdict, seconds)
        if verdict.kind == "ok":
            shutil.rmtree(where, ignore_errors=True)

    try:
        with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
            list(pool.map(one, enumerate(probes)))
    finally:
        if own and not out.failures():
            shutil.rmtree(base, ignore_errors=True)
    out.folder = base
    return out
