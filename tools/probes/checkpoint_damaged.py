"""Class ``checkpoint-damaged``: a checkpoint whose files are damaged (cut short, empty, of the wrong kind,
edited, missing, of another length) is refused by ``--restart`` and by ``initial: {from: ...}``, serially
and under ``mpirun -n 2``: one line naming the damaged file, status 2, at once (no rank left waiting),
nothing written."""

from __future__ import annotations

import json
import os
import shutil

from . import CASES, ok, probe, wrong

BAR = CASES / "impacting_bar.yaml"
COMMON = ("-q", "--set", "output.vtk=false", "--set", "mesh.cells=20", "--set", "solver.dt=0.01")
TIMEOUT = 120.0


def _checkpoint(ctx, ranks: int):
    def build(folder):
        r = ctx.run("run", BAR, "-o", folder / "run", *COMMON, "--set", "solver.t_end=0.05",
                    mpi=ranks if ranks > 1 else 0)
        if r.status != 0:
            raise RuntimeError(f"the checkpoint run failed: {r.tail()}")
    return ctx.shared(f"damaged-checkpoint-{ranks}", build) / "run" / "checkpoint"


def _edit_state(change):
    def damage(folder):
        state = json.loads((folder / "state.json").read_text())
        change(state)
        (folder / "state.json").write_text(json.dumps(state, indent=2))
    return damage


def _edit_rank(rank, change):
    def damage(folder):
        import h5py

        with h5py.File(folder / f"rank-{rank}.h5", "r+") as f:
            change(f)
    return damage


def _cut(name, keep):
    def damage(folder):
        data = (folder / name).read_bytes()
        (folder / name).write_bytes(data[:keep] if keep >= 0 else data[:len(data) // 2])
    return damage


def _longer_U(f):
    import numpy as np

    U = f["integrator/U"][()]
    del f["integrator/U"]
    f["integrator/U"] = np.zeros(U.size + 3)


def _flip(rank):
    def damage(folder):
        import h5py

        file = folder / f"rank-{rank}.h5"
        with h5py.File(file) as f:
            V = f["integrator/V"]
            at = V.id.get_offset() if V.chunks is None else V.id.get_chunk_info(0).byte_offset
        data = bytearray(file.read_bytes())
        data[at + 9] ^= 0x40
        file.write_bytes(bytes(data))
    return damage


def _set_t(value):
    return _edit_state(lambda s: s.update(t=value))


# what: (the file the message must name, the damage); RANK stands for the rank whose file is damaged
DAMAGES = {
    "state.json cut short": ("state.json", _cut("state.json", -1)),
    "state.json empty": ("state.json", _cut("state.json", 0)),
    "state.json a list": ("state.json", lambda d: (d / "state.json").write_text("[0.05, 5]\n")),
    "state.json binary": ("state.json", lambda d: (d / "state.json").write_bytes(os.urandom(400))),
    "state.json nested too deep": ("state.json", lambda d: (d / "state.json").write_text("[" * 10**5 + "]" * 10**5)),
    "t: abc": ("state.json", _set_t("abc")),
    "t: null": ("state.json", _set_t(None)),
    "t: -1": ("state.json", _set_t(-1.0)),
    "t: 1e400": ("state.json", lambda d: (d / "state.json").write_text(
        (d / "state.json").read_text().replace('"t": 0.05', '"t": 1e400'))),
    "t edited to 0.02": ("rank-0.h5", _set_t(0.02)),   # (the rank files hold another time)
    "step edited": ("rank-0.h5", _edit_state(lambda s: s.update(step=2))),
    "no t": ("state.json", _edit_state(lambda s: s.pop("t"))),
    "no step": ("state.json", _edit_state(lambda s: s.pop("step"))),
    "no ranks": ("state.json", _edit_state(lambda s: s.pop("ranks"))),
    "no model": ("state.json", _edit_state(lambda s: s.pop("model"))),
    "model a list": ("state.json", _edit_state(lambda s: s.update(model=[]))),
    "ranks edited": ("state.json", _edit_state(lambda s: s.update(ranks=s["ranks"] + 1))),
    "format 1": ("state.json", _edit_state(lambda s: s.update(format=1))),
    "state.json deleted": ("state.json", lambda d: (d / "state.json").unlink()),
    "RANK missing": ("RANK", lambda d, r: (d / f"rank-{r}.h5").unlink()),
    "RANK cut short": ("RANK", lambda d, r: _cut(f"rank-{r}.h5", -1)(d)),
    "RANK zero bytes": ("RANK", lambda d, r: _cut(f"rank-{r}.h5", 0)(d)),
    "RANK random bytes": ("RANK", lambda d, r: (d / f"rank-{r}.h5").write_bytes(os.urandom(6000))),
    "RANK: integrator group deleted": ("RANK", lambda d, r: _edit_rank(r, lambda f: f.__delitem__("integrator"))(d)),
    "RANK: impacts group deleted": ("RANK", lambda d, r: _edit_rank(r, lambda f: f.__delitem__("impacts"))(d)),
    "RANK: U deleted": ("RANK", lambda d, r: _edit_rank(r, lambda f: f.__delitem__("integrator/U"))(d)),
    "RANK: U of another length": ("RANK", lambda d, r: _edit_rank(r, _longer_U)(d)),
    "RANK: a byte of V flipped": ("RANK", lambda d, r: _flip(r)(d)),
    "RANK: its t edited": ("RANK", lambda d, r: _edit_rank(r, lambda f: f.attrs.__setitem__("t", 0.02))(d)),
    "RANK: energy budget deleted": ("RANK", lambda d, r: _edit_rank(
        r, lambda f: f.__delitem__("integrator/state/energy"))(d)),
}
# (initial.from reads the state vectors alone: a damage elsewhere in a rank file leaves what it reads whole)
RESTART_ONLY = ("RANK: impacts group deleted", "RANK: energy budget deleted")


def _ours(text: str) -> list[str]:
    """fem-impact's lines of stderr (mpirun adds its own block when a rank exits with a non-zero status)."""
    return [line for line in text.splitlines() if line.startswith("fem-impact:")]


def _damaged(what, how, ranks, rank):
    file, damage = DAMAGES[what]

    def body(ctx):
        saved = _checkpoint(ctx, ranks)
        folder = ctx.folder / "damaged"
        shutil.copytree(saved.parent, folder)
        if file == "RANK":
            damage(folder / "checkpoint", rank)
        else:
            damage(folder / "checkpoint")
        ctx.keep(folder)   # (nobody writes into a checkpoint it reads)
        named = folder / "checkpoint" / (f"rank-{rank}.h5" if file == "RANK" else file)
        out = ctx.folder / "out"
        args = ["--restart", folder] if how == "restart" else ["--set", f"initial={{from: {folder}}}"]
        r = ctx.run("run", BAR, "-o", out, *COMMON, "--set", "solver.t_end=0.2", *args, mpi=ranks if ranks > 1 else 0,
                    timeout=TIMEOUT)
        if r.traceback:
            return ctx.refused(r)
        if r.status != 2:
            return wrong(f"status {r.status}: {r.tail()}")
        lines = _ours(r.stderr)
        if len(lines) != 1:
            return wrong(f"{len(lines)} lines of fem-impact's: {r.tail()}")
        if str(named) not in lines[0] and not (what == "state.json deleted" and "no checkpoint there" in lines[0]):
            return wrong(f"the message does not name {named}: {lines[0]}")
        if ("initial.from" if how == "from" else "--restart") not in lines[0]:
            return wrong(f"the message does not say which option: {lines[0]}")
        if out.exists():
            return wrong(f"refused, yet {out} was written")
        return ok(lines[0][:160])
    return body


for _ranks in (1, 2):
    for _what in DAMAGES:
        for _rank in ((0, 1) if "RANK" in _what and _ranks == 2 else (0,)):
            for _how in ("restart", "from"):
                if _how == "from" and _what in RESTART_ONLY:
                    continue
                label = _what.replace("RANK", f"rank-{_rank}.h5")
                where = "mpirun -n 2" if _ranks == 2 else "serial"
                probe("checkpoint-damaged", f"{where}, {'--restart' if _how == 'restart' else 'initial.from'}: {label}",
                      timeout=TIMEOUT + 30)(_damaged(_what, _how, _ranks, _rank))
