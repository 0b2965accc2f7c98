"""The claim of an output folder: the lock against a concurrent run, the debris of killed runs (a killed
run's checkpoint kept), the staging folder, and its install in place under the policy checked again."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import shutil
import threading
import time
from pathlib import Path

from ..._version import __version__
from ...errors import OutputFolderError
from .interruption import (
    TAKE_OVER,
    Interrupted,
    ignore_signals,
    install_signal_handlers,
    received_since,
    signals_so_far,
)
from .manifest import foreign_entries, foreign_refusal, is_result, remove_result, tree, write_marker_data
from .policy import OutputFolderChanged, _keep_beside, _real, _refusal, check
from .writes import CHECKPOINT, OutputWriteError, write_error

log = logging.getLogger(__name__)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_while_written(stage: Path, linger: float) -> None:
    """Remove a staging folder that another rank may still be writing into, and keep it removed for
    ``linger`` seconds. Interrupted under MPI, the signal reaches one rank; another may be inside a
    write that creates the folder again (dolfinx's VTK writer makes its directories) before it waits
    in a collective until mpirun kills it, which would leave an empty ``.NAME.partial-PID`` behind."""
    deadline = time.monotonic() + linger
    while True:
        shutil.rmtree(stage, ignore_errors=True)
        if time.monotonic() >= deadline:
            return
        time.sleep(0.05)


_CLEANUP: list[threading.Thread] = []   # removals of an interrupted run's staging folder, under way


def wait_for_cleanup(timeout: float = 1.5) -> None:
    """Before an interrupted process ends: let the background removal of its staging folder finish."""
    end = time.monotonic() + timeout
    while _CLEANUP:
        _CLEANUP.pop().join(max(0.0, end - time.monotonic()))


def _is_checkpoint(folder: Path) -> bool:
    """A checkpoint folder fem-impact wrote: state.json naming its version, rank-R.h5 files, nothing else."""
    try:
        names = {p.name for p in folder.iterdir()}
        state = json.loads((folder / "state.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(state, dict) and "fem_impact_version" in state and \
        all(n == "state.json" or (n.startswith("rank-") and n.endswith(".h5")) for n in names)


def _keep_checkpoint(folder: Path, path: Path, inputs=()) -> tuple[Path, str] | None:
    """Move the last complete checkpoint written in ``folder`` to ``NAME.checkpoint`` beside the output
    folder ``path`` (an earlier checkpoint of that name is replaced, anything else is kept: the
    checkpoint then goes to ``NAME.checkpoint-TIMESTAMP``; so does it when ``NAME.checkpoint`` is one of
    ``inputs``, what the command reads: a restart's checkpoint); returns (where, its time) or None."""
    try:
        for source in (folder / CHECKPOINT, folder / f"{CHECKPOINT}.old"):   # (.old: interrupted mid-rename)
            if (source / "state.json").is_file():
                break
        else:
            return None
        when = json.loads((source / "state.json").read_text()).get("t")
        target = path.parent / f"{path.name}.checkpoint"
        read = any(_real(target) == _real(p) or _real(target) in _real(p).parents for p in inputs)
        if _is_checkpoint(target) and not read:   # an earlier one, kept the same way: replaced; anything else is left
            shutil.rmtree(target)
        if target.exists():
            target = path.parent / f"{path.name}.checkpoint-{time.strftime('%Y%m%d-%H%M%S')}"
        os.rename(source, target)
        return target, f"t = {when:.6g}"
    except (OSError, ValueError):
        return None
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _remove_stale(parent: Path, name: str, inputs=(), moved=None) -> list[Path]:
    """Staging and replaced folders of ``name`` left by processes that no longer exist; the last checkpoint of
    a killed run is kept in ``NAME.checkpoint`` (and said in a warning), its old and new places in ``moved``."""
    removed = []
    for p in parent.glob(f".{_glob_escape(name)}.checkpoint-*"):   # a killed run's checkpoints: kept
        pid = p.name.rsplit("-", 1)[1]
        if pid.isdigit() and not _alive(int(pid)):
            kept = _keep_checkpoint(p, parent / name, inputs)
            if kept is not None:
                log.warning("the last checkpoint (%s) of a run into %s that was killed is kept in %s: continue it "
                            "with --restart %s", kept[1], parent / name, kept[0], kept[0])
                if moved is not None:
                    moved[str(_real(p))] = str(kept[0])
    for kind in ("partial", "old"):
        for p in parent.glob(f".{_glob_escape(name)}.{kind}-*"):
            pid = p.name.rsplit("-", 1)[1]
            if not (pid.isdigit() and (int(pid) == 0 or not _alive(int(pid)))):
                continue
            if kind == "partial":   # (only ever what a command was writing)
                shutil.rmtree(p, ignore_errors=True)
            elif not os.path.lexists(parent / name):   # killed between its two moves: the earlier result goes back
                with contextlib.suppress(OSError):
                    os.rename(p, parent / name)
                continue
            elif is_result(p):   # (only ever a result moved aside: what fem-impact wrote in it)
                _discard(p, parent / name)
            else:
                continue
            removed.append(p)
    return removed


def _glob_escape(name: str) -> str:
    return "".join(f"[{c}]" if c in "*?[" else c for c in name)


class OutputFolder:
    """A claimed output folder: checked, locked; ``staged()`` writes it atomically."""

    def __init__(self, path: Path, comm, command: str, source=None, inputs=()):
        self.path, self.comm, self.command, self.source = path, comm, command, source
        self.inputs = tuple(p for p in inputs if p is not None)
        self.moved: dict[str, str] = {}   # a killed run's checkpoint folder -> where the claim kept it
        self._lock_fd = None
        self._lock_path = path.parent / f".{path.name}.lock"
        self._created: list[Path] = []
        self.stale: list[Path] = []

    # rank 0 only
    def _acquire(self) -> None:
        missing = []
        p = self.path.parent
        while not p.exists():
            missing.append(p)
            p = p.parent
        try:
            for folder in reversed(missing):
                folder.mkdir()
                self._created.append(folder)
            while True:
                fd = os.open(self._lock_path, os.O_RDWR | os.O_CREAT, 0o644)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError as err:
                    holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                    os.close(fd)
                    if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                        raise OutputFolderError(str(self.path), f"another fem-impact process (pid {holder}) is "
                                                                "writing this folder; wait for it to finish or "
                                                                "choose another folder") from None
                    raise
                # The holder before us may have removed the file after we opened it: lock the file in place.
                try:
                    same = os.fstat(fd).st_ino == os.stat(self._lock_path).st_ino
                except FileNotFoundError:
                    same = False
                if same:
                    break
                os.close(fd)
            self._lock_fd = fd
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            self.stale = _remove_stale(self.path.parent, self.path.name, self.inputs, self.moved)
        except OSError as err:
            self._release()
            raise OutputFolderError(str(self.path), f"cannot create the output folder: "
                                                    f"{err.strerror or err}") from None
        except BaseException:
            self._release()
            raise

    def _release(self, failed: bool = True) -> None:
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                os.unlink(self._lock_path)
            os.close(self._lock_fd)
            self._lock_fd = None
        if failed:   # folders made for the output that stayed empty
            for folder in reversed(self._created):
                with contextlib.suppress(OSError):
                    folder.rmdir()
        self._created = []

    def follow(self, path):
        """Where ``path`` is now: a killed run's checkpoint that this claim moved to ``NAME.checkpoint`` (a
        restart from it reads it there); any other path as it is."""
        if path is None or not self.moved:
            return path
        real = _real(path)
        for old, new in self.moved.items():
            if real == Path(old) or real == Path(old) / CHECKPOINT:
                return Path(new)
        return path

    def write_marker(self, folder: Path, files=()) -> None:
        """The marker of ``folder``, with its manifest ``files`` (relative paths, folders with "/"): written
        whole or not at all."""
        data = {"written_by": f"fem-impact {self.command}", "fem_impact_version": __version__,
                "source": None if self.source is None else str(self.source), "files": sorted(set(files))}
        write_marker_data(Path(folder), data)

    @contextlib.contextmanager
    def staged(self):
        """Write into ``.NAME.partial-PID`` beside the folder; move it over the folder when complete.

        A failed or interrupted body removes the staging folder and leaves the folder as it was; so
        does a failed write (:class:`OutputWriteError`). At the move the policy is checked again
        (:meth:`install`).
        """
        comm = self.comm
        install_signal_handlers()   # again: PETSc, imported meanwhile, installs its own
        signals = signals_so_far()
        stage = self.path.parent / f".{self.path.name}.partial-{os.getpid()}"
        error = None
        if comm.rank == 0:
            try:
                stage.mkdir()
            except OSError as err:
                error = f"cannot create the staging folder {stage}: {err.strerror}"
        error = comm.bcast(error, root=0)
        if error:
            raise OutputFolderError(str(self.path), error)
        stage = Path(comm.bcast(str(stage), root=0))
        # Checkpoints are written beside the staging folder, not in it: an interrupted run keeps the last
        # one (:func:`_keep_checkpoint`) while every rank removes the staging folder.
        self.checkpoints = stage.parent / stage.name.replace(".partial-", ".checkpoint-", 1)
        try:
            yield stage
            if received_since(signals) is not None:   # (its KeyboardInterrupt lost where Python ignores them)
                raise Interrupted(received_since(signals))
            comm.barrier()
            failure = None
            if comm.rank == 0:
                try:
                    saved = self.checkpoints / CHECKPOINT
                    if saved.is_dir():
                        os.rename(saved, stage / CHECKPOINT)
                    shutil.rmtree(self.checkpoints, ignore_errors=True)
                    self.write_marker(stage, tree(stage))
                    self.install(stage)
                    self._created = []   # they hold the result now
                except OutputFolderChanged as err:
                    failure = ("changed", err.file, err.message, str(err.kept))
                except OSError as err:
                    failure = ("write", str(write_error(err, stage, self.path)))
            failure = comm.bcast(failure, root=0)
            if failure is not None:
                raise OutputFolderChanged(*failure[1:]) if failure[0] == "changed" else OutputWriteError(failure[1])
        except BaseException as err:
            interrupted = isinstance(err, KeyboardInterrupt)
            if interrupted:
                ignore_signals()   # a second signal (mpirun sends one) must not cut the cleanup short
            if interrupted and comm.size > 1:
                self._stop_ranks(err, stage)
            elif comm.rank == 0:
                self._keep_last_checkpoint(err)
                shutil.rmtree(stage, ignore_errors=True)
            if isinstance(err, OSError):
                converted = write_error(err, stage, self.path, self.checkpoints)
                converted.left = getattr(err, "left", None)
                raise converted from None
            raise
        comm.barrier()

    def _keep_last_checkpoint(self, err: BaseException) -> None:
        """Keep the run's last checkpoint beside the output folder and say so in ``err.left``."""
        kept = _keep_checkpoint(self.checkpoints, self.path)
        if kept is not None:
            err.left = (f"the output folder was left as it was; the run's last checkpoint ({kept[1]}) is "
                        f"kept in {kept[0]}: continue it with --restart {kept[0]}")

    def _stop_ranks(self, err: KeyboardInterrupt, stage: Path) -> None:
        """An interruption under MPI: one rank keeps the last checkpoint and speaks (``err.speaker``), every rank
        removes the staging folder.

        mpirun passes the signal to every rank and kills them a second later (odls_base_sigkill_timeout); a
        rank inside an MPI call that waits for another never sees it. Rank 0 does it when it can; another rank
        that finds the staging folder still there after :data:`TAKE_OVER` seconds takes over (rank 0 is stuck).
        Who does it is decided by renaming the staging folder away: that succeeds for one rank only. The folder
        is then kept removed for a second in the background (:func:`_remove_while_written`): the line is said
        first (:func:`wait_for_cleanup` before the process ends).
        """
        comm = self.comm
        if comm.rank != 0:
            deadline = time.monotonic() + TAKE_OVER
            while stage.exists() and time.monotonic() < deadline:
                time.sleep(0.02)
        mine = stage.with_name(f"{stage.name}.removing-{os.getpid()}")
        try:
            os.rename(stage, mine)
        except OSError:
            err.speaker = False
        else:
            err.speaker = True
            self._keep_last_checkpoint(err)
        if comm.rank != 0:   # (rank 0, if stuck, is killed with the lock file left)
            with contextlib.suppress(OSError):
                os.unlink(self._lock_path)
        else:
            self._release()   # (before lingering: mpirun may kill this rank meanwhile)
        def remove():
            shutil.rmtree(mine, ignore_errors=True)
            _remove_while_written(stage, linger=1.0)

        thread = threading.Thread(target=remove, daemon=True)
        thread.start()
        _CLEANUP.append(thread)

    def install(self, stage: Path) -> None:
        """Move the complete ``stage`` into place (rank 0, holding the lock), under the policy checked again:
        between the check at the start and now the folder may have appeared or changed.

        The move itself never replaces files: rename(2) puts a folder over an empty folder only, and
        fails on one with files (which may appear between this check and the move). An earlier result
        is first moved aside (``.NAME.old-PID``) and removed once the new one is in place; it is put
        back when the move fails. When the folder holds what is not a result, it is left as it was and
        the result is kept beside it: :class:`OutputFolderChanged`.
        """
        path = self.path
        refusal = _refusal(path)
        old = None
        if refusal is None and path.is_dir() and any(path.iterdir()):
            old = path.parent / f".{path.name}.old-{os.getpid()}"
            try:
                os.rename(path, old)
            except FileNotFoundError:   # (gone meanwhile: nothing to move aside)
                old = None
            else:   # an entry made between the check and the move aside: the folder goes back (below)
                try:
                    late = foreign_entries(old)
                except OSError as err:
                    late = [f"{err.filename}: {err.strerror}"]
                if late:
                    refusal = foreign_refusal(late)
        try:
            if refusal is None:
                try:
                    os.rename(stage, path)
                except OSError as err:
                    if err.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
                        raise
                    refusal = _refusal(path) or "the output path was taken during the run"
        except BaseException:
            if old is not None:
                os.rename(old, path)
            raise
        if refusal is not None:
            earlier = ""
            if old is not None:   # (the folder appeared again between the two renames)
                try:
                    os.rename(old, path)
                except OSError:
                    earlier = f"; the earlier result is in {_keep_beside(old, path)}"
            kept = _keep_beside(stage, path)
            raise OutputFolderChanged(str(path), f"{refusal} (checked again at the end of the {self.command}, "
                                                 f"before the results were moved into place); the results are "
                                                 f"in {kept}{earlier}", kept)
        if old is not None:
            _discard(old, path)


def _discard(old: Path, path: Path) -> None:
    """Remove the earlier result ``old`` (moved aside from ``path``): what fem-impact wrote in it. An entry of
    the user's that is still there (made in it after the last check, through a process's open folder) goes
    to the same place in ``path`` when that is free, else stays in ``old``: never removed."""
    left = remove_result(old)
    if not left:
        return
    for name in left:
        source, target = old / name.rstrip("/"), path / name.rstrip("/")
        if target.parent.is_dir() and not os.path.lexists(target):
            with contextlib.suppress(OSError):
                os.rename(source, target)
    remove_result(old)


@contextlib.contextmanager
def claim(outdir, comm, command: str, protect=(), source=None):
    """Check and lock ``outdir`` for the body; yields an :class:`OutputFolder`.

    Raises OutputFolderError (on every rank) when the policy refuses the folder or another
    process holds it. On leaving, the lock is released; on failure, parent folders this claim
    created are removed again if empty.
    """
    install_signal_handlers()
    out = None
    error = None
    if comm.rank == 0:
        try:
            path = check(outdir, protect)
            out = OutputFolder(path, comm, command, source, protect)
            out._acquire()
        except OutputFolderError as err:
            error = (err.file, err.message)
    error = comm.bcast(error, root=0)
    if error:
        raise OutputFolderError(*error)
    moved = comm.bcast(out.moved if comm.rank == 0 else None, root=0)
    if comm.rank != 0:
        out = OutputFolder(Path(os.path.abspath(outdir)), comm, command, source, protect)
        out.moved = moved
    ok = False
    try:
        yield out
        ok = True
    finally:
        if comm.rank == 0:
            out._release(failed=not ok)
