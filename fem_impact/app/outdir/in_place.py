"""A folder written in place, not through a staging folder: a study's, whose completed levels stay when
it fails or is interrupted, for a rerun to resume."""

from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path

from ...errors import OutputFolderError
from .claim import OutputFolder, claim
from .manifest import _STUDY_CACHE, LEVELS, MARKER, owned_entries
from .policy import _refusal
from .writes import _WRITTEN, write_error, writing


_IN_PLACE: set[str] = set()   # the folders this process's written_in_place claims hold now


@contextlib.contextmanager
def in_place(outdir, command: str, protect=(), source=None):
    """:func:`written_in_place` for a study called from Python; nothing more when this process holds that claim
    already (the command line claims the folder before it calls the study)."""
    if os.path.realpath(outdir) in _IN_PLACE:
        yield None
        return
    from mpi4py import MPI

    with written_in_place(outdir, MPI.COMM_WORLD, command, protect, source) as out:
        yield out


@contextlib.contextmanager
def written_in_place(outdir, comm, command: str, protect=(), source=None):
    """Claim ``outdir`` for a command that writes into it directly, not through a staging folder: a study,
    whose completed levels (``OUTDIR/levels/NAME``) are kept for a rerun to resume.

    The folder is made at once (mkdir, which does not take over a folder that appeared since the
    check: that one is checked again). The marker is written at once only into a new or empty folder
    (so that it is recognized with its first level); into an earlier result, at completion.

    Leaving with an error, the exception gets ``left``, one sentence on what the folder keeps: the
    levels this run completed, or "the output folder was left as it was" (then what this claim made
    is removed again). An OSError becomes :class:`OutputWriteError`.
    """
    with claim(outdir, comm, command, protect, source) as out:
        made, before, before_files, error = set(), {}, [], None
        if comm.rank == 0:
            try:
                made = _open_in_place(out)
                before = _levels(out.path)
                before_files = owned_entries(out.path)
            except OutputFolderError as err:
                error = (err.file, err.message)
            except OSError as err:
                error = (str(out.path), f"cannot create the output folder: {err.strerror or err}")
        error = comm.bcast(error, root=0)
        if error:
            raise OutputFolderError(*error)
        held = os.path.realpath(out.path)
        _IN_PLACE.add(held)
        try:
            yield out
            if comm.rank == 0:
                with writing(out.path / MARKER):
                    out.write_marker(out.path, _in_place_manifest(out.path, before_files))
        except BaseException as err:
            if comm.rank == 0:
                err.left = _left_in_place(out.path, before, made)
            if isinstance(err, OSError):
                converted = write_error(err, final=out.path)
                converted.left = getattr(err, "left", None)
                raise converted from None
            raise
        finally:
            _IN_PLACE.discard(held)


def _in_place_manifest(folder: Path, before: list[str]) -> list[str]:
    """What a study's folder holds of the program's at its end: the earlier result's entries that are still
    there and the files this study wrote (its levels are known as such: not listed)."""
    real = os.path.realpath(folder) + os.sep
    mine = {p for p in _WRITTEN if p.startswith(real)}
    _WRITTEN.difference_update(mine)
    files = set()
    for rel in [*before, *(p[len(real):].replace(os.sep, "/") for p in mine)]:
        if rel == MARKER or rel.startswith(LEVELS + "/") or not os.path.lexists(folder / rel.rstrip("/")):
            continue
        files.add(rel)
        parts = rel.rstrip("/").split("/")
        files.update("/".join(parts[:k]) + "/" for k in range(1, len(parts)))
    return sorted(files)


def _open_in_place(out: OutputFolder) -> set:
    """Make the folder (or check it again) for writing in place; returns what was made: "folder", "marker"."""
    made = set()
    try:
        out.path.mkdir()
        made.add("folder")
    except FileExistsError:
        refusal = _refusal(out.path)
        if refusal is not None:
            raise OutputFolderError(str(out.path), refusal) from None
    if "folder" in made or not any(out.path.iterdir()):
        out.write_marker(out.path)
        made.add("marker")
    for cache in out.path.glob(".cache-*"):   # a killed study's private cache (we hold the lock)
        if _STUDY_CACHE.fullmatch(cache.name) and cache.is_dir() and not cache.is_symlink():
            shutil.rmtree(cache, ignore_errors=True)
    if not (out.path / "levels").exists():
        made.add("levels")
    return made


def _levels(folder: Path) -> dict:
    """The recorded levels of a study folder: name -> identity of its ``level.json`` (rewritten by replace)."""
    found = {}
    for record in (folder / "levels").glob("*/level.json"):
        with contextlib.suppress(OSError):
            st = record.stat()
            found[record.parent.name] = (st.st_ino, st.st_mtime_ns)
    return found


def _left_in_place(folder: Path, before: dict, made: set) -> str:
    """What a study that ends early leaves in its folder, in words; when it recorded no level, what it
    made is removed (the folder, the marker, an empty ``levels/``), so that the folder is as it was."""
    now = _levels(folder)
    new = [name for name, ident in now.items() if before.get(name) != ident]
    if new:
        others = len(now) - len(new)
        return (f"{len(new)} completed level{'s' if len(new) > 1 else ''} of this run "
                f"{'are' if len(new) > 1 else 'is'} kept in {folder / 'levels'}"
                + (f", with {others} of an earlier run" if others else "")
                + "; run the same command again to resume")
    try:
        if "levels" in made and (folder / "levels").exists():
            (folder / "levels").rmdir()
        if "marker" in made:
            (folder / MARKER).unlink()
        if "folder" in made:
            folder.rmdir()
    except OSError:   # (something else was left in it: a killed level's staging folder)
        return "no level was completed"
    return "the output folder was left as it was"
