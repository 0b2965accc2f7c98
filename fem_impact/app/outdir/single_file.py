"""A single output file (a picture of ``plot``, an animation): an existing file is replaced only by one
of its kind, and the new one is put in place whole, never over another file."""

from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path

from ...errors import OutputFolderError
from .manifest import adopt
from .policy import MAX_NAME_BYTES, OutputFolderChanged, _keep_beside, _real
from .writes import write_error, writing


_MAGIC = {".png": (b"\x89PNG",), ".gif": (b"GIF8",), ".jpg": (b"\xff\xd8",), ".jpeg": (b"\xff\xd8",),
          ".pdf": (b"%PDF",), ".svg": (b"<?xml", b"<svg"), ".mp4": (b"ftyp",)}


def check_file(output, protect=(), option: str = "-o") -> Path:
    """An output file (a picture, an animation): its folder must exist; an existing file is replaced
    only when it is a picture of the same kind, never a folder or another file."""
    text = os.fspath(output)
    if not text.strip():
        raise OutputFolderError(f"{option} {text!r}", "give a file name")
    if "\0" in text:
        raise OutputFolderError(f"{option} {text!r}", "a file name cannot hold a NUL character")
    path = Path(os.path.abspath(text))
    if len(os.fsencode(path.name)) > MAX_NAME_BYTES:
        raise OutputFolderError(f"{option} {text[:60]}...", "the file name is too long")
    if not path.parent.is_dir():
        raise OutputFolderError(f"{option} {text}", f"no folder {path.parent}" if not path.parent.exists()
                                else f"{path.parent} is not a folder")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise OutputFolderError(f"{option} {text}", f"cannot write into {path.parent} (permission denied)")
    if any(_real(path) == _real(p) for p in protect if p is not None):
        raise OutputFolderError(f"{option} {text}", "is an input of this command; choose another file")
    refusal = _file_refusal(path)
    if refusal is not None:
        raise OutputFolderError(f"{option} {text}", refusal)
    return path


def _file_refusal(path: Path) -> str | None:
    """Why a picture must not replace what ``path`` is now; None for nothing there or a picture of its kind."""
    if path.is_dir():
        return "is a folder; give a file name"
    if not path.exists():
        return None
    magic = _MAGIC.get(path.suffix.lower(), ())
    try:
        with open(path, "rb") as f:
            head = f.read(12)
    except OSError as err:
        return f"cannot read the existing file: {err.strerror}"
    if not any(head.startswith(m) or m in head[:12] for m in magic):
        return (f"the file exists and is not a {path.suffix or 'picture'} picture; it is left as it was (choose "
                "another name)")
    return None


@contextlib.contextmanager
def atomic_file(path: Path):
    """Yields a temporary name beside ``path`` (same suffix); it replaces ``path`` when the body completes.

    The temporary file is made first: a place where no file can be made is refused
    (:class:`OutputFolderError`); a write that fails later is :class:`OutputWriteError`. At the end
    :func:`check_file`'s policy is checked again: a file that appeared meanwhile and is not a picture of
    the kind is left as it was, and the picture kept beside it (:class:`OutputFolderChanged`).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644))
    except OSError as err:
        raise OutputFolderError(str(path), f"cannot write the file: {err.strerror or err}") from None
    try:
        with writing(path):
            yield tmp
            _install_file(tmp, path)
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if err.filename is not None and os.fsdecode(err.filename) == str(tmp):
            err.filename = str(path)
        raise write_error(err) from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _install_file(tmp: Path, path: Path) -> None:
    """Put the finished ``tmp`` at ``path`` under the policy checked again; never over another file: a new
    name is taken with link(2), which fails on whatever exists (rename would replace it)."""
    refusal = _file_refusal(path)
    if refusal is None and not path.exists():
        try:
            os.link(tmp, path)
        except FileExistsError:
            refusal = _file_refusal(path) or "a file of that name was made during the rendering"
        except OSError as err:
            if err.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK):
                raise
            os.replace(tmp, path)   # (no hard links on this file system: the check just made must do)
            adopt(path)
            return
        else:
            os.unlink(tmp)
            adopt(path)
            return
    if refusal is None:
        os.replace(tmp, path)   # a picture of the kind, replaced
        adopt(path)
        return
    kept = _keep_beside(tmp, path)
    raise OutputFolderChanged(str(path), f"{refusal} (checked again before the picture was written); the picture "
                                         f"is in {kept}", kept)
