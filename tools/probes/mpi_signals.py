"""Class ``mpi-signals``: SIGTERM, SIGINT and SIGHUP to ``mpirun -n 2`` (and to one of its ranks) and to
serial runs, with and without ``output.checkpoint_every``, at different moments (while the run sets up,
as its time loop starts, once it has saved a checkpoint, while it saves one); a run killed outright
(SIGKILL); and restarts from what an interrupted or killed run kept, into the same ``-o`` and another.

The contract: one line ``fem-impact: interrupted by SIG (...)`` on stderr naming the checkpoint kept in
``NAME.checkpoint`` when there is one; the earlier result in ``-o`` as it was; no staging folder, lock or
hidden checkpoint left behind (a killed run's hidden checkpoint is kept in ``NAME.checkpoint`` by the next
command into the folder); status 128 + the signal for a serial run (mpirun itself exits with 1 when it
received the signal, or with a rank's status when that rank was signalled); a restart from the kept
checkpoint continues from its time; a restart from a hidden checkpoint that the claim of its output
folder moves follows it, never "no checkpoint there"."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

from . import CASES, lost, ok, probe, wrong

BAR = CASES / "impacting_bar.yaml"
QUICK = ("--set", "mesh.cells=10", "--set", "solver.dt=0.01", "--set", "solver.t_end=0.05")
# A time loop of minutes (interrupted long before its end): 0.4 s of simulated time per 200 steps.
LONG = ("--set", "output.vtk=false", "--set", "solver.t_end=400")
CHECKPOINTS = ("--set", "output.checkpoint_every=200")
OFTEN = ("--set", "output.checkpoint_every=5")
NAME = "m"


# -- helpers ------------------------------------------------------------------------------------
def _earlier(ctx, keep: bool = True) -> Path:
    """ctx.folder/m holding an earlier result (built once, copied); ``keep``: remembered as the user's (no
    command of the probe may change it; a probe whose restart replaces it checks it with :func:`_same`)."""
    def build(work):
        r = ctx.run("run", BAR, "-q", "-o", work, *QUICK)
        if r.status != 0:
            raise RuntimeError(f"the earlier result could not be made: {r.tail()}")

    out = ctx.shared(NAME, build)
    if keep:
        ctx.keep(out)
    return out


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _glob(ctx, pattern):
    return list(ctx.folder.glob(pattern))


def _moment(ctx, moment):
    """When to send the signal: seconds after the start, or a condition on what the run has written."""
    if moment == "setup":
        return 1.5
    if moment == "building":   # (the mesh, the model: collective calls)
        return 3.0
    if moment == "loop":
        return lambda: bool(_glob(ctx, f".{NAME}.partial-*"))
    if moment == "checkpoint":
        return lambda: bool(_glob(ctx, f".{NAME}.checkpoint-*/checkpoint/state.json"))
    if moment == "saving":   # a checkpoint being written (one every 5 steps) after a first one
        return lambda: bool(_glob(ctx, f".{NAME}.checkpoint-*/checkpoint/state.json")) and \
            bool(_glob(ctx, f".{NAME}.checkpoint-*/checkpoint.new"))
    raise ValueError(moment)


def _ranks(out: Path) -> dict[int, int]:
    """The MPI ranks (rank -> pid) of the fem-impact processes writing ``out`` (this probe's own: the folder
    is the probe's)."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
            if str(out).encode() not in argv or b"fem_impact" not in argv:
                continue
            environ = dict(item.split(b"=", 1) for item in (entry / "environ").read_bytes().split(b"\0") if b"=" in item)
        except OSError:
            continue
        rank = environ.get(b"OMPI_COMM_WORLD_RANK")
        if rank is not None:
            found[int(rank)] = int(entry.name)
    return found


def _debris(ctx) -> list[str]:
    return sorted(p.name for p in ctx.folder.iterdir()
                  if p.name.startswith(f".{NAME}.") or p.name.startswith(f"{NAME}.result-"))


def _no_debris(ctx, wait: float = 2.0) -> list[str]:
    """What is left beside the folder once the processes have gone (the staging folder is kept removed for a
    second after an interruption under MPI)."""
    deadline = time.monotonic() + wait
    while _debris(ctx) and time.monotonic() < deadline:
        time.sleep(0.1)
    return _debris(ctx)


def _kept(ctx) -> Path | None:
    kept = ctx.folder / f"{NAME}.checkpoint"
    return kept if (kept / "state.json").is_file() else None


def _judge_interrupt(ctx, r, sig, mpi, checkpoint_expected, sent_to_mpirun=True):
    """One line, the checkpoint kept and named when one was saved, no debris, the expected status."""
    if r.traceback:
        return ctx.refused(r)   # (reports the traceback)
    lines = [line for line in r.lines() if line.startswith("fem-impact:")]
    if len(lines) != 1 or not lines[0].startswith("fem-impact: interrupted by "):
        return wrong(f"{len(lines)} fem-impact lines (status {r.status}): {r.tail(4)}")
    if sent_to_mpirun and len(r.lines()) != 1:
        return wrong(f"{len(r.lines())} lines on stderr: {r.tail(4)}")
    if not mpi and r.status != 128 + sig:
        return wrong(f"status {r.status}, expected {128 + sig}")
    if mpi and r.status in (0, None):
        return wrong(f"status {r.status}")
    kept = _kept(ctx)
    if checkpoint_expected and (kept is None or f"--restart {kept}" not in lines[0]):
        return wrong(f"no checkpoint kept in {NAME}.checkpoint, or not named: {lines[0]}")
    if kept is not None and f"--restart {kept}" not in lines[0]:
        return wrong(f"a checkpoint was kept in {kept} but the line does not say so: {lines[0]}")
    left = _no_debris(ctx)
    if left:
        return wrong(f"left beside the folder: {left}")
    return ok(lines[0][:160])


# -- interruptions --------------------------------------------------------------------------------
def _interrupt_probe(sig, mpi, moment, checkpoints):
    label = (f"{signal.Signals(sig).name} to {'mpirun -n 2' if mpi else 'a serial run'} {MOMENTS[moment]}"
             f"{', with output.checkpoint_every' if checkpoints else ''}")
    extra = (OFTEN if moment == "saving" else CHECKPOINTS) if checkpoints else ()

    def body(ctx):
        out = _earlier(ctx)
        r = ctx.run("run", BAR, "-q", "-o", out, *LONG, *extra, mpi=2 if mpi else 0,
                    signal_at=(_moment(ctx, moment), sig))
        return _judge_interrupt(ctx, r, sig, mpi, checkpoint_expected=moment in ("checkpoint", "saving"))

    probe("mpi-signals", label, timeout=240)(body)


MOMENTS = {"setup": "while it sets up", "building": "3 s after its start", "loop": "as its time loop starts", "checkpoint": "after a checkpoint",
           "saving": "while it saves checkpoints"}

for _sig, _moments in ((signal.SIGTERM, ("setup", "building", "loop", "checkpoint", "saving")),
                       (signal.SIGINT, ("building", "loop", "checkpoint")),
                       (signal.SIGHUP, ("loop", "checkpoint"))):
    for _m in _moments:
        _interrupt_probe(_sig, True, _m, checkpoints=_m not in ("loop", "building"))
_interrupt_probe(signal.SIGTERM, True, "loop", checkpoints=True)
for _sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
    _interrupt_probe(_sig, False, "checkpoint", checkpoints=True)
_interrupt_probe(signal.SIGTERM, False, "loop", checkpoints=False)
_interrupt_probe(signal.SIGINT, False, "setup", checkpoints=False)


def _one_rank_probe(rank):
    @probe("mpi-signals", f"SIGTERM to rank {rank} of mpirun -n 2 only, after a checkpoint", timeout=240)
    def body(ctx):
        out = _earlier(ctx)
        saved = _moment(ctx, "checkpoint")

        def signal_rank():
            if not saved():
                return False
            pids = _ranks(out)
            if rank not in pids:
                return False
            os.kill(pids[rank], signal.SIGTERM)
            return True

        r = ctx.run("run", BAR, "-q", "-o", out, *LONG, *CHECKPOINTS, mpi=2, signal_at=(signal_rank, 0))
        verdict = _judge_interrupt(ctx, r, signal.SIGTERM, True, True, sent_to_mpirun=False)
        if verdict.kind == "ok" and r.status != 128 + signal.SIGTERM:
            return wrong(f"status {r.status}: mpirun passes on the signalled rank's 143")
        return verdict
    return body


_one_rank_probe(0)
_one_rank_probe(1)


# -- restarts -------------------------------------------------------------------------------------
def _saved_time(folder: Path) -> float:
    return json.loads((folder / "state.json").read_text())["t"]


def _judge_restart(ctx, r, out, t0):
    """A restart that ran: status 0, its summary says it started from ``t0``, its history starts there."""
    if r.traceback:
        return ctx.refused(r)
    if "no checkpoint there" in r.stderr:
        return wrong(f"lost its checkpoint: {r.tail()}")
    if r.status != 0:
        return wrong(f"status {r.status}: {r.tail()}")
    summary = json.loads((out / "summary.json").read_text())
    start = (summary.get("restarted_from") or {}).get("t")
    if start is None or abs(start - t0) > 1e-12 * max(1.0, abs(t0)):
        return wrong(f"restarted from t = {start}, the checkpoint is at t = {t0}")
    with open(out / "history.csv") as f:
        f.readline()
        first = float(f.readline().split(",")[0])
    if abs(first - t0) > 1e-9 * max(1.0, abs(t0)):
        return wrong(f"the history starts at t = {first}, not at the checkpoint's {t0}")
    return ok(f"from t = {t0:.6g}")


def _interrupted_with_checkpoint(ctx, sig, mpi):
    """An interrupted run's kept checkpoint (NAME.checkpoint), or a verdict."""
    out = _earlier(ctx, keep=False)
    before = _files(out)
    r = ctx.run("run", BAR, "-q", "-o", out, *LONG, *CHECKPOINTS, mpi=2 if mpi else 0,
                signal_at=(_moment(ctx, "checkpoint"), sig))
    verdict = _judge_interrupt(ctx, r, sig, mpi, checkpoint_expected=True)
    if _files(out) != before:
        verdict = lost("the interrupted run changed the earlier result")
    return out, (_kept(ctx) if verdict.kind == "ok" else verdict)


def _restart_probe(sig, mpi, same):
    where = "the same -o" if same else "another -o"

    @probe("mpi-signals", f"restart from what {signal.Signals(sig).name} to {'mpirun -n 2' if mpi else 'a serial run'} "
                          f"kept, into {where}", timeout=300)
    def body(ctx):
        out, kept = _interrupted_with_checkpoint(ctx, sig, mpi)
        if not isinstance(kept, Path):
            return kept
        t0 = _saved_time(kept)
        target = out if same else ctx.folder / "n"
        r = ctx.run("run", BAR, "-q", "-o", target, *LONG[:2], "--set", f"solver.t_end={t0 + 0.2}", "--restart", kept,
                    mpi=2 if mpi else 0)
        return _judge_restart(ctx, r, target, t0)
    return body


_restart_probe(signal.SIGTERM, False, True)
_restart_probe(signal.SIGTERM, True, False)
_restart_probe(signal.SIGINT, True, True)


def _killed(ctx, mpi):
    """A run killed outright (SIGKILL to every process) after a checkpoint: its hidden checkpoint folder."""
    out = _earlier(ctx, keep=False)
    before = _files(out)
    saved = _moment(ctx, "checkpoint")

    def kill_all():
        if not saved():
            return False
        pids = _ranks(out)
        if len(pids) < (2 if mpi else 1):
            return False
        for pid in pids.values():
            os.kill(pid, signal.SIGKILL)
        return True

    if mpi:
        r = ctx.run("run", BAR, "-q", "-o", out, *LONG, *CHECKPOINTS, mpi=2, signal_at=(kill_all, 0))
    else:
        r = ctx.run("run", BAR, "-q", "-o", out, *LONG, *CHECKPOINTS, signal_at=(saved, signal.SIGKILL))
    hidden = _glob(ctx, f".{NAME}.checkpoint-*")
    if _files(out) != before:
        return out, lost("the killed run changed the earlier result")
    if r.status == 0 or len(hidden) != 1 or not (hidden[0] / "checkpoint" / "state.json").is_file():
        return out, wrong(f"status {r.status}, hidden checkpoints {[h.name for h in hidden]}: {r.tail()}")
    return out, hidden[0]


def _hidden_restart_probe(mpi, same, inner):
    what = "its checkpoint/ folder" if inner else "the hidden folder"

    @probe("mpi-signals", f"restart from a killed {'mpirun -n 2' if mpi else 'serial'} run's hidden checkpoint "
                          f"({what}) into {'the same -o' if same else 'another -o'}", timeout=300)
    def body(ctx):
        out, hidden = _killed(ctx, mpi)
        if not isinstance(hidden, Path):
            return hidden
        source = hidden / "checkpoint" if inner else hidden
        t0 = _saved_time(hidden / "checkpoint")
        target = out if same else ctx.folder / "n"
        r = ctx.run("run", BAR, "-q", "-o", target, *LONG[:2], "--set", f"solver.t_end={t0 + 0.2}", "--restart",
                    source, mpi=2 if mpi else 0)
        if r.status == 2 and not r.traceback and "checkpoint" in r.stderr and "no checkpoint there" not in r.stderr \
                and len(r.lines()) == 1:
            return ok(f"refused clearly: {r.tail(1)}")
        verdict = _judge_restart(ctx, r, target, t0)
        if verdict.kind != "ok":
            return verdict
        if not same and not (hidden / "checkpoint" / "state.json").is_file() and _kept(ctx) is None:
            return lost("the killed run's checkpoint is gone")
        return verdict
    return body


_hidden_restart_probe(False, True, False)
_hidden_restart_probe(False, True, True)
_hidden_restart_probe(False, False, False)
_hidden_restart_probe(True, True, False)


@probe("mpi-signals", "a killed run's hidden checkpoint is kept by the next run into the folder, and said",
       timeout=300)
def _hidden_kept_by_next(ctx):
    out, hidden = _killed(ctx, False)
    if not isinstance(hidden, Path):
        return hidden
    t0 = _saved_time(hidden / "checkpoint")
    r = ctx.run("run", BAR, "-q", "-o", out, *QUICK)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    kept = _kept(ctx)
    if kept is None or _saved_time(kept) != t0:
        return lost(f"the killed run's checkpoint (t = {t0}) is not in {NAME}.checkpoint")
    if str(kept) not in r.stderr:
        return wrong(f"kept in {kept} without a word: {r.tail()}")
    return ok(r.tail(1)[:160])


@probe("mpi-signals", "a restart from NAME.checkpoint never reads another killed run's checkpoint", timeout=400)
def _restart_source_not_replaced(ctx):
    """NAME.checkpoint kept by an interrupted run (t1); then another run killed outright leaves a hidden one
    (t2): a restart from NAME.checkpoint into the same folder continues from t1, as asked."""
    out, kept = _interrupted_with_checkpoint(ctx, signal.SIGTERM, False)
    if not isinstance(kept, Path):
        return kept
    t1 = _saved_time(kept)
    r = ctx.run("run", BAR, "-q", "-o", out, *LONG, "--set", "output.checkpoint_every=100",
                signal_at=(lambda: bool(_glob(ctx, f".{NAME}.checkpoint-*/checkpoint/state.json")), signal.SIGKILL))
    if r.status != 128 + signal.SIGKILL:
        return wrong(f"the second run was not killed: status {r.status}")
    r = ctx.run("run", BAR, "-q", "-o", out, *LONG[:2], "--set", f"solver.t_end={t1 + 0.2}", "--restart", kept)
    return _judge_restart(ctx, r, out, t1)


@probe("mpi-signals", "SIGTERM to mpirun -n 2 during a restarted run: its checkpoint kept again, restartable",
       timeout=400)
def _interrupt_restarted(ctx):
    out, kept = _interrupted_with_checkpoint(ctx, signal.SIGTERM, True)
    if not isinstance(kept, Path):
        return kept
    t0 = _saved_time(kept)
    before = kept.stat().st_mtime_ns
    moment = lambda: bool(_glob(ctx, f".{NAME}.checkpoint-*/checkpoint/state.json"))  # noqa: E731
    r = ctx.run("run", BAR, "-q", "-o", out, *LONG, *CHECKPOINTS, "--restart", kept, mpi=2,
                signal_at=(moment, signal.SIGTERM))
    verdict = _judge_interrupt(ctx, r, signal.SIGTERM, True, checkpoint_expected=True)
    if verdict.kind != "ok":
        return verdict
    again = _kept(ctx)
    t1 = _saved_time(again)
    if t1 <= t0 and again.stat().st_mtime_ns == before:
        return wrong(f"the restarted run's checkpoint (after t = {t0}) was not kept: {r.tail(1)}")
    r = ctx.run("run", BAR, "-q", "-o", ctx.folder / "n", *LONG[:2], "--set", f"solver.t_end={t1 + 0.2}",
                "--restart", again, mpi=2)
    return _judge_restart(ctx, r, ctx.folder / "n", t1)
