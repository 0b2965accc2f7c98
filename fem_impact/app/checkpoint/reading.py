"""Reading a checkpoint: ``state.json`` and every rank's file checked (a damaged one refused in one line
naming the file), the ranks agreeing before any goes on; the parts restored, or redistributed when the
mesh was partitioned otherwise."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ...integrators.parameters import REDUCED
from .keys import _shown, differences, unknowns_keys
from .layout import FOLDER, FORMAT, PARTS, STATE, _digest, _plain, _read
from .state import _kind, check, restore


class Damaged(Exception):
    """A checkpoint's file that does not hold what it should: ``file`` and what is wrong with it."""

    def __init__(self, file, message: str):
        super().__init__(f"{file}: {message}")
        self.file, self.message = str(file), message


def find(path, option: str = "--restart") -> Path:
    """The checkpoint folder of ``path``: a run's output folder, or the checkpoint folder itself."""
    path = Path(path)
    for folder in (path / FOLDER, path):
        if (folder / STATE).is_file():
            return folder
    raise Damaged(path, f"no checkpoint there (neither {path / FOLDER / STATE} nor {path / STATE}"
                        f"{'' if path.is_dir() else ': no such folder'}); a run saves one at its end and every "
                        f"output.checkpoint_every steps")


class Saved:
    """A checkpoint whose ``state.json`` was read and checked: its ``folder`` and ``state`` (the dict)."""

    def __init__(self, folder: Path, state: dict):
        self.folder, self.state = folder, state

    @property
    def t(self) -> float:
        return self.state["t"]

    @property
    def step(self) -> int:
        return self.state["step"]


def agree(comm, problem: Damaged | None) -> None:
    """Raise the first problem any rank found (in rank order), on every rank: one collective call, which every
    rank makes, so that no rank goes on (or waits) while another stops."""
    found = comm.allgather(None if problem is None else (problem.file, problem.message)) if comm.size > 1 \
        else [None if problem is None else (problem.file, problem.message)]
    first = next((p for p in found if p is not None), None)
    if first is not None:
        raise Damaged(*first)


def open_checkpoint(path, comm) -> Saved:
    """The checkpoint at ``path`` with its state.json read and checked on every rank (Damaged: the
    file and what is wrong, the same on every rank)."""
    problem, saved = None, None
    try:
        folder = find(path)
        saved = Saved(folder, _read_state(folder / STATE, comm))
    except Damaged as err:
        problem = err
    agree(comm, problem)
    return saved


# state.json's keys: (what they must be, a check)
_STATE_KEYS = {
    "t": ("a time >= 0", lambda v: _is_real(v) and math.isfinite(v) and v >= 0.0),
    "step": ("a step count >= 0", lambda v: _is_int(v) and v >= 0),
    "ranks": ("a count of ranks >= 1", lambda v: _is_int(v) and v >= 1),
    "model": ("a mapping of keys", lambda v: isinstance(v, dict)),
    "loads": ("a mapping of keys", lambda v: isinstance(v, dict)),
    "dofs": ("a count of dofs >= 1", lambda v: _is_int(v) and v >= 1),
    "modes": ("a count of modes or null", lambda v: v is None or (_is_int(v) and v >= 1)),
}


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _read_state(file: Path, comm) -> dict:
    try:
        text = file.read_bytes().decode("utf-8")
        state = json.loads(text)
    except OSError as err:
        raise Damaged(file, f"cannot be read ({err.strerror or err})") from None
    except UnicodeDecodeError:
        raise Damaged(file, "is not text: a checkpoint's state.json is JSON (the checkpoint is damaged)") from None
    except (ValueError, RecursionError) as err:   # (RecursionError: nested beyond what Python reads)
        what = "empty" if not text.strip() else f"not valid JSON ({getattr(err, 'msg', err)} at line " \
                                                 f"{getattr(err, 'lineno', '?')}): truncated or damaged"
        raise Damaged(file, f"is {what}; the checkpoint cannot be read") from None
    if not isinstance(state, dict):
        raise Damaged(file, f"holds {_kind(state)}, not a checkpoint's mapping of keys (the checkpoint is damaged)")
    version = state.get("format")
    if version != FORMAT:
        if version == 1:
            raise Damaged(file, "was written by an earlier fem-impact (checkpoint format 1), which did not record "
                                f"what its state depends on; this version reads format {FORMAT}: run the case again")
        raise Damaged(file, f"has format {_shown(version) if 'format' in state else 'none'}: not a checkpoint this "
                            f"version reads (format {FORMAT})")
    for key, (what, ok) in _STATE_KEYS.items():
        if key not in state:
            raise Damaged(file, f"has no '{key}' (the checkpoint is damaged)")
        if not ok(state[key]):
            raise Damaged(file, f"'{key}' is {_shown(state[key])}, not {what} (the checkpoint is damaged or was "
                                "edited)")
    if state["ranks"] != comm.size:
        raise Damaged(file, f"the checkpoint was written on {state['ranks']} MPI rank(s), this run has {comm.size}: "
                            "run with as many")
    return state


def read_parts(saved: Saved, comm, now: dict, dof_keys: np.ndarray | None = None) -> dict:
    """This rank's parts of the checkpoint (``capture``'s trees by part), its files checked against
    state.json and the run's ``now`` (``dofs``, ``modes``: the model it built), every rank agreeing."""
    problem, parts = None, None
    try:
        state, folder = saved.state, saved.folder
        for key, what in (("dofs", "dofs"), ("modes", "modes kept by the reduced model")):
            if state.get(key) != now.get(key):
                hint = (" (modes: auto chooses the count from solver.dt, solver.t_end, output.every and the loads: "
                        f"give solver.modes: {state[key]})" if key == "modes" and state[key] and now.get(key) else "")
                raise Damaged(folder / STATE, f"the checkpoint's model has {state.get(key)} {what}, this case's "
                                              f"{now.get(key)}{hint}")
        parts, keys = _read_rank(folder, comm.rank, state, full=dof_keys is not None)
        if dof_keys is not None and not np.array_equal(keys, dof_keys):
            parts = _redistributed(folder, state, parts, dof_keys)
    except Damaged as err:
        problem = err
    agree(comm, problem)
    return parts


def _read_rank(folder: Path, rank: int, state: dict, full: bool) -> tuple[dict, np.ndarray | None]:
    """(parts, dof keys) of ``rank-R.h5``, checked: it belongs to this checkpoint (its t, step, rank and
    state.json's digest), holds every part, and (``full``) the dofs' numbers."""
    import h5py

    file = folder / f"rank-{rank}.h5"
    if not file.is_file():
        raise Damaged(file, "missing: the checkpoint is incomplete (each MPI rank writes its own file)")
    try:
        with h5py.File(file, "r") as f:
            stamp = {key: _plain(f.attrs[key]) if key in f.attrs else None
                     for key in ("format", "rank", "t", "step", "state_digest")}
            expected = {"format": FORMAT, "rank": rank, "t": state["t"], "step": state["step"],
                        "state_digest": _digest(state)}
            wrong = [key for key in expected if stamp[key] != expected[key]]
            if wrong:
                raise Damaged(file, _mismatch(wrong, stamp, expected))
            missing = [name for name in PARTS if name not in f]
            if missing:
                raise Damaged(file, f"has no {', '.join(missing)} (the checkpoint is damaged)")
            parts = {name: _read(f[name]) for name in f if name != "dof_keys"}
            keys = np.asarray(f["dof_keys"][()]) if "dof_keys" in f else None
    except Damaged:
        raise
    except (OSError, KeyError, ValueError, TypeError, IndexError, AttributeError, RuntimeError) as err:
        raise Damaged(file, f"cannot be read ({type(err).__name__}: {_reason(err)}): the checkpoint is damaged"
                            " (truncated, or not a checkpoint's file)") from None
    if full and (keys is None or keys.ndim != 1 or keys.dtype.kind not in "iu"):
        raise Damaged(file, "has no numbers of its dofs (dof_keys): the checkpoint is damaged")
    step_state = parts["integrator"].get("state")
    if not (isinstance(step_state, tuple) and len(step_state) == 3 and isinstance(step_state[2], dict)
            and step_state[2].get("t") == state["t"] and step_state[2].get("step") == state["step"]):
        raise Damaged(file, "its integrator's state is not at the checkpoint's t and step (the checkpoint is "
                            "damaged)")
    return parts, keys


def _mismatch(wrong: list, stamp: dict, expected: dict) -> str:
    if "format" in wrong or "rank" in wrong:
        return (f"is not this checkpoint's file for rank {expected['rank']} (its format {_shown(stamp['format'])}, "
                f"rank {_shown(stamp['rank'])})")
    if "t" in wrong or "step" in wrong:
        return (f"holds the state at t = {_shown(stamp['t'])} (step {_shown(stamp['step'])}), state.json says "
                f"t = {expected['t']!r} (step {expected['step']}): the files are of different checkpoints, or "
                "state.json was edited")
    return "does not belong to this state.json (another checkpoint's file, or state.json was edited)"


def _reason(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 120 else text[:100] + "..."


def restore_parts(parts: dict, trees: dict, saved: Saved, comm) -> None:
    """Restore each part from its tree, after checking every one fits (Damaged naming the rank's file
    and the attribute), every rank agreeing first."""
    problem = None
    file = saved.folder / f"rank-{comm.rank}.h5"
    for name, part in parts.items():
        try:
            if name not in trees:
                raise ValueError("missing")
            check(part, trees[name])
        except ValueError as err:
            problem = Damaged(file, f"its {name} does not fit this case: {err} (the checkpoint is damaged)")
            break
    agree(comm, problem)
    for name, part in parts.items():
        restore(part, trees[name])


def initial_state(path, comm, model: dict, reduced: bool, now: dict, U0, dof_keys=None):
    """(U, V) of the saved run at ``path``: its integrator's state vectors (nodal values, or the reduced
    model's modal coordinates), for a run that starts where it ended (``initial: {from: DIR}``). The time
    step, the loads, the method and the model's other keys may differ; what the unknowns are (the mesh;
    for the reduced model its modes) and the ranks must not (Damaged: which file, what differs)."""
    saved = open_checkpoint(path, comm)
    differ = differences(unknowns_keys(saved.state["model"], reduced_of(saved.state)),
                         unknowns_keys(model, reduced))
    if differ:
        raise Damaged(saved.folder / STATE, f"its unknowns are not this case's: {', '.join(differ)}")
    parts = read_parts(saved, comm, now, dof_keys)
    size = np.asarray(U0.array_r if hasattr(U0, "array_r") else U0).size
    problem = None
    state = parts.get("integrator", {})
    U, V = state.get("U"), state.get("V")
    if not all(isinstance(x, np.ndarray) and x.ndim == 1 and x.dtype.kind == "f" for x in (U, V)):
        problem = Damaged(saved.folder / f"rank-{comm.rank}.h5", "holds no state vectors U and V (damaged)")
    elif U.size != size or V.size != size:
        problem = Damaged(saved.folder / f"rank-{comm.rank}.h5", f"its state has {U.size} unknowns on this rank, "
                                                                 f"the case {size} (another mesh or count of modes)")
    agree(comm, problem)
    return U.copy(), V.copy()


def reduced_of(state: dict) -> bool:
    """Whether a checkpoint's run was of the reduced model."""
    return state.get("model", {}).get("solver.method") == REDUCED


def _redistributed(folder: Path, state: dict, mine: dict, dof_keys: np.ndarray) -> dict:
    """This rank's parts when the mesh was distributed otherwise than in the saved run (the partitioner
    numbers nodes its own way each time): every vector of owned dofs is gathered from all ranks' files
    by the dofs' partition-independent numbers. (Each rank reads every file: N values a rank, once.)"""
    trees, keys = [], []
    for r in range(state["ranks"]):
        tree, k = _read_rank(folder, r, state, full=True)
        trees.append(tree)
        keys.append(k)
    all_keys = np.concatenate(keys)
    order = np.argsort(all_keys, kind="stable")
    where = order[np.minimum(np.searchsorted(all_keys[order], dof_keys), all_keys.size - 1)]
    if not all_keys.size or not np.array_equal(all_keys[where], dof_keys):
        raise Damaged(folder, "its dofs are not this case's (another mesh?)")

    def remap(values, path):
        first = values[0]
        if isinstance(first, dict):   # a part: its attributes
            return {k: remap([v[k] for v in values], path + (k,)) for k in first}
        if isinstance(first, np.ndarray):
            local = all(v.ndim == 1 and v.size == k.size for v, k in zip(values, keys))
            # (a p-vector the ranks share may have the length of every rank's owned dofs, by chance)
            replicated = len(values) > 1 and all(v.shape == first.shape and np.array_equal(v, first) for v in values)
            if local and not (replicated and first.size):
                return np.concatenate(values)[where]
            return mine_at(path)
        if isinstance(first, tuple) and first and first[0] in ("dataclass", "list", "tuple", "dict", "object"):
            if first[0] == "dataclass":
                return ("dataclass", first[1], {k: remap([v[2][k] for v in values], path + (k,)) for k in first[2]})
            if first[0] in ("list", "tuple"):
                return (first[0], [remap([v[1][i] for v in values], path + (i,)) for i in range(len(first[1]))])
            return (first[0], {k: remap([v[1][k] for v in values], path + (k,)) for k in first[1]})
        return mine_at(path)

    def mine_at(path):
        node = mine
        for part in path:
            node = node[part] if isinstance(node, dict) else (node[2][part] if node[0] == "dataclass" else node[1][part])
        return node

    try:
        return {name: remap([t[name] for t in trees], (name,)) for name in mine}
    except (KeyError, IndexError, TypeError, ValueError):
        raise Damaged(folder, "its rank files do not hold the same parts (the checkpoint is damaged)") from None
