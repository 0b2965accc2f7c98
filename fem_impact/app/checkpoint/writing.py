"""The run's checkpoints: written every ``output.checkpoint_every`` steps and at the end, into
``checkpoint.new/`` renamed over ``checkpoint/`` once every rank's file is there."""

from __future__ import annotations

import io
import json
import os
import shutil
from pathlib import Path

import numpy as np

from ..._version import __version__
from ...integrators.state import StepState
from .layout import FOLDER, FORMAT, STATE, _digest, _write
from .state import capture


class Checkpoints:
    """An observer that saves the run's parts every ``every`` steps (0: at the end only) and at the end."""

    def __init__(self, folder: Path, comm, parts: dict, meta: dict, every: int, last_step: int,
                 dof_keys: np.ndarray | None = None):
        self.folder, self.comm, self.parts, self.meta = Path(folder), comm, parts, meta
        self.dof_keys = dof_keys   # the owned dofs' partition-independent numbers (the full model's vectors)
        self.every, self.last_step = every, last_step
        self.saved_at: float | None = None

    def _due(self, step: int) -> bool:
        return step == self.last_step or bool(self.every and step % self.every == 0 and step)

    def write(self, state: StepState) -> None:
        if self._due(state.step):
            self.save(state)

    def next_stop(self, step: int) -> int:
        """The next step after ``step`` at which a checkpoint is saved: no block of steps runs past it."""
        if not self.every:
            return self.last_step
        return min(self.last_step, (step // self.every + 1) * self.every)

    def write_block(self, block) -> None:
        """After a block (integrators/blocks.py), the integrator holds its last step: saved when due."""
        if self._due(int(block.step[-1])):
            self.save(block.state(len(block) - 1))

    def save(self, state: StepState) -> None:
        """Write the state into ``checkpoint.new/`` and rename it over ``checkpoint/`` once every rank's file is
        there. A write that fails (a full disk) raises the same OSError, naming the file, on every rank: each
        rank's HDF5 file is made in memory and written as plain bytes, so that HDF5 never holds a file it
        cannot write (its failed close leaves the process to crash at exit)."""
        import h5py

        comm = self.comm
        new, final = self.folder / f"{FOLDER}.new", self.folder / FOLDER
        meta = json.loads(json.dumps(dict(self.meta, format=FORMAT, t=float(state.t), step=int(state.step),
                                          ranks=comm.size, fem_impact_version=__version__)))
        error = None
        if comm.rank == 0:
            try:
                shutil.rmtree(new, ignore_errors=True)
                new.mkdir(parents=True)
            except OSError as err:
                error = _error_of(err, new)
        _raise_any(comm.bcast(error, root=0))
        path = new / f"rank-{comm.rank}.h5"
        try:
            # Made in memory, written as plain bytes: on a full disk h5py's own write fails midway and its
            # close fails again at exit.
            image = io.BytesIO()
            with h5py.File(image, "w") as f:
                f.attrs.update(format=FORMAT, rank=comm.rank, ranks=comm.size, t=meta["t"], step=meta["step"],
                               state_digest=_digest(meta))
                if self.dof_keys is not None:
                    f.create_dataset("dof_keys", data=self.dof_keys, fletcher32=bool(self.dof_keys.size))
                for name, part in self.parts.items():
                    _write(f.create_group(name), capture(part))
            with open(path, "wb") as out:
                out.write(image.getbuffer())
        except OSError as err:
            error = _error_of(err, path)
        _raise_any(next((e for e in comm.allgather(error) if e is not None), None))
        if comm.rank == 0:
            try:
                try:
                    (new / STATE).write_text(json.dumps(meta, indent=2) + "\n")
                except OSError as err:
                    raise OSError(err.errno, err.strerror, str(new / STATE)) from None
                old = self.folder / f"{FOLDER}.old"
                if final.exists():
                    os.rename(final, old)
                os.rename(new, final)
                shutil.rmtree(old, ignore_errors=True)
            except OSError as err:
                error = _error_of(err, new)
        _raise_any(comm.bcast(error, root=0))
        self.saved_at = state.t


def _error_of(err: OSError, path: Path) -> tuple:
    """An OSError as plain data (to send to every rank), naming ``path`` when it names no file."""
    return (err.errno, err.strerror or str(err), os.fsdecode(err.filename) if err.filename is not None else str(path))


def _raise_any(error) -> None:
    if error is not None:
        raise OSError(*error)
