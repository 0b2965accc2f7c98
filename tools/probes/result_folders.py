"""Class ``result-folders``: files of the user's in a result folder survive every command that writes
the folder again (a rerun, a rerun that fails, a study), or the command refuses with status 2 naming
them; nothing the program did not write is ever removed."""

from __future__ import annotations

from . import CASES, lost, ok, probe, wrong

BLOCK = CASES / "sliding_block.yaml"
SHORT = ("--set", "solver.t_end=0.02")


def _first_run(ctx):
    out = ctx.folder / "x"
    r = ctx.run("run", BLOCK, "-q", "-o", out, *SHORT)
    return out, ctx.succeeded(r)


def _user_files(out):
    (out / "analysis.ipynb").write_text("notes\n")
    (out / "figures").mkdir()
    (out / "figures" / "f.png").write_text("p\n")


def _judge_rerun(ctx, r, out):
    """A rerun over the user's files: kept in place (status 0) or a refusal naming them (status 2)."""
    if r.status == 0 and not r.traceback:
        return ok("kept") if (out / "analysis.ipynb").is_file() else lost("the rerun removed the user's files")
    return ctx.refused(r, "analysis.ipynb")


@probe("result-folders", "rerun over a notebook and a folder of figures")
def _rerun(ctx):
    out, bad = _first_run(ctx)
    if bad:
        return bad
    _user_files(out)
    ctx.keep(out / "figures")
    r = ctx.run("run", BLOCK, "-q", "-o", out, "--set", "solver.t_end=0.04")
    return _judge_rerun(ctx, r, out)


@probe("result-folders", "rerun that fails (bad input) over user files")
def _rerun_fails(ctx):
    out, bad = _first_run(ctx)
    if bad:
        return bad
    _user_files(out)
    ctx.keep(out)
    r = ctx.run("run", BLOCK, "-q", "-o", out, "--set", "solver.dt=-1")
    return ctx.refused(r, "solver.dt")


@probe("result-folders", "a user file written into the folder during the rerun")
def _during(ctx):
    out, bad = _first_run(ctx)
    if bad:
        return bad
    note = out / "notes.txt"

    def write_note():
        # once the rerun has started its loop (its staging folder exists), the user saves a note
        if any(ctx.folder.glob(".x.partial-*")):
            note.write_text("written during the run\n")
            return True
        return False

    import threading
    import time

    def writer():
        t0 = time.monotonic()
        while time.monotonic() - t0 < 60 and not write_note():
            time.sleep(0.01)

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    r = ctx.run("run", BLOCK, "-q", "-o", out, "--set", "solver.t_end=0.4")
    thread.join(timeout=1)
    if not note.exists():
        # the note must be there still (in place), or the rerun refused and kept its result beside
        return lost("the note written during the run is gone")
    if r.traceback:
        return ctx.refused(r)
    if r.status not in (0, 2):
        return wrong(f"status {r.status}: {r.tail()}")
    return ok()
