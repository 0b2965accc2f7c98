"""Writing results: a file replaced whole or not at all, an OSError naming the file, and the one line
(:class:`OutputWriteError`, status 3) for a write that fails (a full disk, a quota, an I/O error)."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from ...errors import SimulationError

CHECKPOINT = "checkpoint"   # the folder of a run's checkpoint in its result (fem_impact/app/checkpoint/ writes it)


class OutputWriteError(SimulationError):
    """Results that could not be written (a full disk, a quota, an I/O error): the run fails (status 3)."""


def write_error(err: OSError, stage: Path | None = None, final: Path | None = None,
                checkpoints: Path | None = None) -> OutputWriteError:
    """The one line for an OSError while writing results: the file (as it would be named in ``final``
    when it lies in the staging folder ``stage``, or in the run's ``checkpoints`` folder beside it) and
    the system's reason."""
    name = err.filename
    if name is not None and stage is not None and final is not None:
        with contextlib.suppress(ValueError):
            name = final / Path(os.fsdecode(name)).relative_to(stage)
    if name is not None and checkpoints is not None and final is not None:
        with contextlib.suppress(ValueError):
            inside = Path(os.fsdecode(name)).relative_to(checkpoints).parts   # (checkpoint.new/rank-0.h5)
            name = final.joinpath(CHECKPOINT, *inside[1:])
    if err.filename2 is not None:   # a rename: the move into place
        what = f"cannot move the results into {final if final is not None else os.fsdecode(err.filename2)}"
    elif name is not None:
        what = f"cannot write {os.fsdecode(name)}"
    else:
        what = f"cannot write the results{f' into {final}' if final is not None else ''}"
    return OutputWriteError(f"{what}: {err.strerror or err}")


@contextlib.contextmanager
def writing(path):
    """An OSError of the body names ``path`` (a failed ``write`` or ``close`` of a file object names none)."""
    try:
        yield
    except OSError as err:
        if err.filename is None:
            raise OSError(err.errno, err.strerror or str(err), os.fspath(path)) from None
        raise


@contextlib.contextmanager
def replacing(path):
    """Yields a temporary name beside ``path``; it replaces ``path`` when the body completes and is removed
    when it fails (errors name ``path``): a file is either the old one or the new one, whole."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        with writing(path):
            yield tmp
            os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _WRITTEN.add(os.path.realpath(path))


# The files this process wrote in place (replacing): a study's marker lists those of its folder.
_WRITTEN: set[str] = set()
