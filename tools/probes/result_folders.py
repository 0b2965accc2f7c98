"""Class ``result-folders``: files of the user's in a result folder survive every command that writes
the folder again (a rerun, a rerun that fails, a study, a sweep, a reduction, modes, a picture), or the
command refuses with status 2 naming them; nothing the program did not write is ever removed.

The user's files take every shape: a file and a folder at the top, a file nested in the result's own
folders (``checkpoint/``, a sweep's ``run01/``, a study's ``levels/``), hidden files, symbolic links (to a
file, to a folder of the user's elsewhere), a file written while the rerun runs, and results of an
earlier version (a marker without its manifest, or no marker at all)."""

from __future__ import annotations

import json
import os
import shutil
import threading
import time

from . import CASES, lost, ok, probe, wrong

BLOCK = CASES / "sliding_block.yaml"
BAR = CASES / "impacting_bar.yaml"
SHORT = ("--set", "solver.t_end=0.02")
SMALL = ("--set", "mesh.cells=10", "--set", "solver.dt=0.01", "--set", "solver.t_end=0.05")

# The central difference scheme far beyond its stable step: a blow-up in the time loop (status 3).
BLOW_UP = ("run", BAR, "-q", "--set", "solver.method=central_difference", "--set", "solver.mass=lumped",
           "--set", "solver.dt=0.05", "--set", "solver.t_end=40", "--set", "output.vtk=false")

# The commands that write a folder, each as (arguments before -o, arguments of a second run that differs).
COMMANDS = {
    "run": (("run", BLOCK, "-q", *SHORT), ("run", BLOCK, "-q", "--set", "solver.t_end=0.04")),
    "sweep": (("sweep", BAR, "--vary", "solver.dt=0.01,0.02", "-q", *SMALL[:2], *SMALL[4:]),
              ("sweep", BAR, "--vary", "solver.dt=0.01,0.025", "-q", *SMALL[:2], *SMALL[4:])),
    "study": (("study", "convergence", BAR, "--vary", "mesh.cells=10,20", "-q", "--set", "solver.t_end=0.2"),
              ("study", "convergence", BAR, "--vary", "mesh.cells=10,20,40", "-q", "--set", "solver.t_end=0.2")),
    "reduction": (("reduction", BAR, "--modes", "2", *SMALL), ("reduction", BAR, "--modes", "3", *SMALL)),
    "modes": (("modes", BAR, "-n", "2", "-q", *SMALL[:2]), ("modes", BAR, "-n", "3", "-q", *SMALL[:2])),
}


def _first(ctx, command="run", name="x"):
    out = ctx.folder / name
    r = ctx.run(*COMMANDS[command][0], "-o", out)
    return out, ctx.succeeded(r)


def _user_files(out):
    (out / "analysis.ipynb").write_text("notes\n")
    (out / "figures").mkdir()
    (out / "figures" / "f.png").write_text("p\n")


def _judge(ctx, r, out, *names, needle=None):
    """A command over the user's files ``names`` (relative to ``out``): kept in place (status 0) or a refusal
    naming them (status 2); the harness checks the kept files byte for byte."""
    gone = [n for n in names if not os.path.lexists(out / n)]
    if gone:
        return lost(f"{gone} removed (status {r.status}: {r.tail()})")
    if r.status == 0 and not r.traceback:
        return ok("kept in place")
    return ctx.refused(r, needle or names[0].split("/")[0], max_lines=1)


def _rerun_over(command, place, label):
    """Probe: the second run of ``command`` into its result, which holds the user's file made by ``place``."""
    def body(ctx):
        out, bad = _first(ctx, command)
        if bad:
            return bad
        names = place(out)
        _keep(ctx, out, names)
        r = ctx.run(*COMMANDS[command][1], "-o", out)
        return _judge(ctx, r, out, *names)
    probe("result-folders", f"{command} rerun over {label}")(body)


def _keep(ctx, out, names):
    """The user's files ``names`` (under ``out``) must stay as they are; the command may rewrite its own."""
    for name in names:
        ctx.keep(out / name)


def _top(out):
    _user_files(out)
    return ["analysis.ipynb", "figures/f.png"]


def _hidden(out):
    (out / ".notes").write_text("hidden notes\n")
    (out / ".ipynb_checkpoints").mkdir()
    (out / ".ipynb_checkpoints" / "a-checkpoint.ipynb").write_text("{}\n")
    return [".notes", ".ipynb_checkpoints/a-checkpoint.ipynb"]


def _nested(out):
    """A file inside a folder the command wrote (its first subfolder)."""
    sub = sorted(p for p in out.iterdir() if p.is_dir() and not p.name.startswith("."))
    inside = sub[0] if sub else out
    if sub and inside.name == "levels":
        inside = sorted(p for p in inside.iterdir() if p.is_dir())[0]
    (inside / "my-notes.txt").write_text("mine\n")
    return [str((inside / "my-notes.txt").relative_to(out))]


def _collides(out):
    """A hidden file named like a staging folder's temporary file, with a process id that does not exist."""
    (out / ".history.partial-4194303.txt").write_text("mine, oddly named\n")
    (out / ".cache-mine").mkdir()
    (out / ".cache-mine" / "keep.txt").write_text("mine\n")
    return [".cache-mine/keep.txt", ".history.partial-4194303.txt"]


for _command in COMMANDS:
    _rerun_over(_command, _top, "a notebook and a folder of figures")
    _rerun_over(_command, _hidden, "hidden files")
for _command in ("run", "sweep", "study"):
    _rerun_over(_command, _nested, "a file nested in a folder the command wrote")
_rerun_over("run", _collides, "hidden names that look like the program's")


@probe("result-folders", "rerun that fails (bad input) over user files")
def _rerun_fails(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    _user_files(out)
    ctx.keep(out)
    r = ctx.run("run", BLOCK, "-q", "-o", out, "--set", "solver.dt=-1")
    return ctx.refused(r, "solver.dt")


@probe("result-folders", "rerun that fails in its time loop over an earlier result")
def _rerun_blows_up(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    ctx.keep(out)
    r = ctx.run(*BLOW_UP, "-o", out)
    if r.traceback:
        return ctx.refused(r)
    if r.status != 3:
        return wrong(f"status {r.status}, expected 3 (a blow-up): {r.tail()}")
    return ok(r.tail(1))


@probe("result-folders", "rerun that fails over user files nested in checkpoint/")
def _rerun_fails_nested(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    (out / "checkpoint" / "why.txt").write_text("my note on this checkpoint\n")
    _keep(ctx, out, ["checkpoint/why.txt"])
    r = ctx.run("run", BLOCK, "-q", "-o", out, "--set", "solver.t_end=0.04")
    return _judge(ctx, r, out, "checkpoint/why.txt")


@probe("result-folders", "a user file written into the folder during the rerun")
def _during(ctx):
    return _during_body(ctx, "run", ("run", BLOCK, "-q", "--set", "solver.t_end=0.4"))


@probe("result-folders", "a user file written into a sweep's folder during its rerun")
def _during_sweep(ctx):
    return _during_body(ctx, "sweep", ("sweep", BAR, "--vary", "solver.dt=0.002,0.001", "-q", *SMALL[:2],
                                       "--set", "solver.t_end=1"))


def _during_body(ctx, command, rerun):
    out, bad = _first(ctx, command)
    if bad:
        return bad
    note = out / "notes.txt"

    def writer():
        # once the rerun has started its loop (its staging folder exists), the user saves a note
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120:
            if any(ctx.folder.glob(".x.partial-*")):
                note.write_text("written during the run\n")
                return
            time.sleep(0.01)

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    r = ctx.run(*rerun, "-o", out)
    thread.join(timeout=1)
    if not note.exists():
        # the note must be there still (in place), or the rerun refused and kept its result beside
        return lost("the note written during the run is gone")
    if r.traceback:
        return ctx.refused(r)
    if r.status == 0:
        return ok("kept in place")
    kept = sorted(ctx.folder.glob("x.result-*"))
    if r.status != 2 or not kept or "notes.txt" not in r.stderr or str(kept[0]) not in r.stderr:
        return wrong(f"status {r.status}, results kept beside: {[k.name for k in kept]}: {r.tail()}")
    return ok(r.tail(1))


@probe("result-folders", "a symbolic link to a folder of the user's elsewhere")
def _symlink_folder(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    data = ctx.folder / "data"
    data.mkdir()
    (data / "measurements.csv").write_text("t,x\n0,1\n")
    ctx.keep(data)
    os.symlink(data, out / "data")
    r = ctx.run(*COMMANDS["run"][1], "-o", out)
    return _judge(ctx, r, out, "data")


@probe("result-folders", "a symbolic link to a file of the user's, named like an output")
def _symlink_file(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    (ctx.folder / "mine").mkdir()
    mine = ctx.folder / "mine" / "my-history.csv"
    mine.write_text("my own history\n")
    ctx.keep(mine.parent)
    (out / "impacts.csv").unlink()
    os.symlink(mine, out / "impacts.csv")   # the program's name, the user's link: the link may go, the file not
    r = ctx.run(*COMMANDS["run"][1], "-o", out)
    if not mine.is_file() or mine.read_text() != "my own history\n":
        return lost("the file the link pointed to was changed")
    if r.status == 0 and not r.traceback:
        return ok("replaced the link")
    return ctx.refused(r, "impacts.csv", max_lines=1)


def _strip_manifest(out):
    marker = out / ".fem-impact.json"
    data = json.loads(marker.read_text())
    data.pop("files", None)
    marker.write_text(json.dumps(data))


@probe("result-folders", "an earlier version's result (marker without manifest) with user files")
def _legacy_marker(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    _strip_manifest(out)
    _user_files(out)
    _keep(ctx, out, ["analysis.ipynb", "figures/f.png"])
    r = ctx.run(*COMMANDS["run"][1], "-o", out)
    return _judge(ctx, r, out, "analysis.ipynb", "figures/f.png")


@probe("result-folders", "an earlier version's result (no marker, summary.json) with user files")
def _legacy_summary(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    (out / ".fem-impact.json").unlink()
    (out / "thesis.tex").write_text("\\documentclass{article}\n")
    _keep(ctx, out, ["thesis.tex"])
    r = ctx.run(*COMMANDS["run"][1], "-o", out)
    return _judge(ctx, r, out, "thesis.tex")


@probe("result-folders", "an earlier version's result (marker without manifest) is replaced")
def _legacy_replaced(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    _strip_manifest(out)
    r = ctx.run(*COMMANDS["run"][1], "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    summary = json.loads((out / "summary.json").read_text())
    if abs(summary["t_end"] - 0.04) > 1e-9:
        return wrong(f"the result was not replaced: t_end {summary['t_end']}")
    return ok()


@probe("result-folders", "an earlier version's sweep (no manifest) with a file in run01/")
def _legacy_sweep(ctx):
    out, bad = _first(ctx, "sweep")
    if bad:
        return bad
    _strip_manifest(out)
    (out / "run01" / "remarks.txt").write_text("# mine\n")
    _keep(ctx, out, ["run01/remarks.txt"])
    r = ctx.run(*COMMANDS["sweep"][1], "-o", out)
    return _judge(ctx, r, out, "run01/remarks.txt")


@probe("result-folders", "a rerun over its own result (nothing of the user's) replaces it")
def _plain_rerun(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    r = ctx.run(*COMMANDS["run"][1], "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    if abs(json.loads((out / "summary.json").read_text())["t_end"] - 0.04) > 1e-9:
        return wrong("the result was not replaced")
    left = [p.name for p in ctx.folder.iterdir() if p.name.startswith(".x.")]
    return wrong(f"debris left: {left}") if left else ok()


@probe("result-folders", "plot and animate into the result, then a rerun replaces it")
def _pictures_then_rerun(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    for args in (("plot", out), ("animate", out, "--frame", "0"), ("animate", out, "-o", out / "movie.gif")):
        bad = ctx.succeeded(ctx.run(*args))
        if bad:
            return bad
    r = ctx.run(*COMMANDS["run"][1], "-o", out)
    return ctx.succeeded(r) or ok()


@probe("result-folders", "plot -o onto a file of the user's that is not a picture")
def _plot_over_text(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    mine = ctx.folder / "fig.png"
    mine.write_text("my caption, not a picture\n")
    ctx.keep(ctx.folder)
    return ctx.refused(ctx.run("plot", out, "-o", mine), "fig.png", max_lines=1)


@probe("result-folders", "animate -o onto a file of the user's that is not an animation")
def _animate_over_text(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    mine = out / "talk.gif"
    mine.write_text("the slides' notes\n")
    ctx.keep(ctx.folder)
    return ctx.refused(ctx.run("animate", out, "-o", mine), "talk.gif", max_lines=1)


@probe("result-folders", "plot -o into a folder of the user's inside the result, then a rerun")
def _plot_into_user_folder(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    (out / "figures").mkdir()
    bad = ctx.succeeded(ctx.run("plot", out, "-o", out / "figures" / "history.png"))
    if bad:
        return bad
    ctx.keep(out / "figures")
    r = ctx.run(*COMMANDS["run"][1], "-o", out)
    return _judge(ctx, r, out, "figures/history.png", needle="figures/")


@probe("result-folders", "a study rerun over a file in its levels/ folder")
def _study_levels(ctx):
    out, bad = _first(ctx, "study")
    if bad:
        return bad
    (out / "levels" / "README.txt").write_text("what these levels are\n")
    _keep(ctx, out, ["levels/README.txt"])
    r = ctx.run(*COMMANDS["study"][1], "-o", out)
    return _judge(ctx, r, out, "levels/README.txt")


@probe("result-folders", "a study with -j 2 over a run's result holding a user file")
def _study_over_run(ctx):
    out, bad = _first(ctx, "run")
    if bad:
        return bad
    _user_files(out)
    _keep(ctx, out, ["analysis.ipynb", "figures/f.png"])
    r = ctx.run(*COMMANDS["study"][1], "-j", "2", "-o", out)
    return _judge(ctx, r, out, "analysis.ipynb", "figures/f.png")


@probe("result-folders", "a study resumed after a study killed outright (SIGKILL)")
def _study_killed(ctx):
    import signal

    out = ctx.folder / "x"
    args = ("study", "convergence", BAR, "--vary", "mesh.cells=10,20,400", "--set", "solver.t_end=2", "-q")
    r = ctx.run(*args, "-o", out, signal_at=(lambda: len(list(out.glob("levels/*/level.json"))) >= 1,
                                              signal.SIGKILL))
    if r.status != 128 + signal.SIGKILL:
        return wrong(f"the study ended before it was killed (status {r.status}): {r.tail()}")
    r = ctx.run(*args[:4], "mesh.cells=10,20", *args[5:], "-o", out)
    return ctx.succeeded(r) or ok()


@probe("result-folders", "stale debris of a killed rerun holding a user file is never removed")
def _stale_old(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    # a rerun killed between its two moves left the earlier result aside, with a note the user had put in it
    aside = ctx.folder / ".x.old-4194303"
    shutil.copytree(out, aside)
    (aside / "note.txt").write_text("mine\n")
    shutil.rmtree(out)
    r = ctx.run(*COMMANDS["run"][1], "-o", out)
    where = [p for p in (out / "note.txt", aside / "note.txt") if p.is_file()]
    if not where:
        return lost("the note in the earlier result moved aside was removed")
    if r.traceback:
        return ctx.refused(r)
    if r.status not in (0, 2):
        return wrong(f"status {r.status}: {r.tail()}")
    return ok(f"status {r.status}, the note in {where[0].relative_to(ctx.folder)}")


@probe("result-folders", "a killed rerun's earlier result moved aside comes back")
def _stale_old_restored(ctx):
    out, bad = _first(ctx)
    if bad:
        return bad
    before = (out / "history.csv").read_bytes()
    aside = ctx.folder / ".x.old-4194303"
    os.rename(out, aside)   # killed between its two moves: the folder is missing, its earlier result aside
    r = ctx.run(*COMMANDS["run"][0], "-o", ctx.folder / "y")   # (another folder: x's debris is x's)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    r = ctx.run(*BLOW_UP, "-o", out)   # fails in its loop: the claim put the earlier result back, left as it was
    if r.status != 3 or r.traceback:
        return wrong(f"status {r.status}, expected 3 (a blow-up): {r.tail()}")
    if (out / "history.csv").is_file() and (out / "history.csv").read_bytes() == before and not aside.exists():
        return ok()
    return wrong(f"x: {sorted(p.name for p in out.iterdir()) if out.exists() else 'missing'}, aside: {aside.exists()}")
