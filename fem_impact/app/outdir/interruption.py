"""Interruption: SIGTERM, SIGHUP and SIGQUIT end a run as Ctrl-C does (:class:`Interrupted`, a
KeyboardInterrupt), a signal ignored at the start stays ignored, and the exit status is 128 + the signal."""

from __future__ import annotations

import os
import signal
import sys
import time

# Under MPI, how long a rank other than 0 waits for rank 0 to clean up after an interruption before it does.
TAKE_OVER = 0.3


class Interrupted(KeyboardInterrupt):
    """A run ended by a signal (SIGTERM, SIGHUP, SIGQUIT, SIGINT): a KeyboardInterrupt with ``signum``."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


HANDLED = (signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


_RECEIVED: list[int] = []


def _raise(signum, frame):
    # The process is ending: a second signal (mpirun follows one with another, a user presses Ctrl-C
    # twice) must not interrupt the cleanup. The next claim() installs the handlers again.
    ignore_signals()
    _RECEIVED.append(signum)
    raise Interrupted(signum)


def signals_so_far() -> int:
    """How many signals have interrupted this process so far (``received_since``'s mark)."""
    return len(_RECEIVED)


def received_since(mark: int) -> int | None:
    """The signal that interrupted this process since ``mark`` (``signals_so_far``), or None. Python runs a
    signal's handler between bytecodes, also inside a weakref callback or a ``__del__``: the KeyboardInterrupt
    raised there is printed as "Exception ignored" and lost, and the run would go on to its end as if never
    interrupted. A command asks this before it puts its result in place."""
    return _RECEIVED[-1] if len(_RECEIVED) > mark else None


def received() -> int | None:
    """The signal that interrupted this process (a library may have turned the KeyboardInterrupt raised in
    its code into an error of its own: an extension's import fails), or None."""
    return _RECEIVED[-1] if _RECEIVED else None


def rank_zero_stuck(wait: float = TAKE_OVER) -> bool:
    """Under mpirun, interrupted on a rank other than 0: whether rank 0 is still running ``wait`` seconds
    later (stuck in an MPI call that waits for this rank; it exits at once when it can say so itself). Rank 0
    is found among this process's siblings (the ranks mpirun starts on this machine); False when it is not."""
    pid = _rank_zero_pid()
    if pid is None:
        return False
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        if not _running(pid):
            return False
        time.sleep(0.02)
    return _running(pid)


def _rank_zero_pid() -> int | None:
    parent, me = os.getppid(), os.getpid()
    try:
        entries = [e.name for e in os.scandir("/proc") if e.name.isdigit() and int(e.name) != me]
    except OSError:
        return None
    for pid in entries:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if int(f.read().rsplit(")", 1)[1].split()[1]) != parent:
                    continue
            with open(f"/proc/{pid}/environ", "rb") as f:
                env = f.read().split(b"\0")
        except (OSError, ValueError, IndexError):
            continue
        if b"OMPI_COMM_WORLD_RANK=0" in env or b"PMI_RANK=0" in env:
            return int(pid)
    return None


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (OSError, IndexError):
        return False


_IGNORED_AT_START: frozenset | None = None
_PLAIN_UNRAISABLE_HOOK = None


def _quiet_unraisable(unraisable) -> None:
    """An Interrupted raised where Python cannot raise it (a weakref callback, a ``__del__``) is lost, and was
    printed as "Exception ignored" with a traceback: it is recorded (``received_since``, which the command
    asks), so nothing is printed; anything else as Python would."""
    if isinstance(unraisable.exc_value, Interrupted):
        return
    _PLAIN_UNRAISABLE_HOOK(unraisable)


def install_signal_handlers() -> None:
    """SIGTERM, SIGHUP, SIGQUIT and SIGINT raise :class:`Interrupted` (in the main thread; else nothing).

    A signal the process was started with ignored stays ignored (``nohup`` ignores SIGHUP, a shell script's
    background command SIGINT): the run goes on, as the one who started it asked. (Noted at the first call;
    PETSc, imported later, installs handlers of its own, which the next call replaces.)"""
    global _IGNORED_AT_START, _PLAIN_UNRAISABLE_HOOK
    if _PLAIN_UNRAISABLE_HOOK is None:
        _PLAIN_UNRAISABLE_HOOK, sys.unraisablehook = sys.unraisablehook, _quiet_unraisable
    if _IGNORED_AT_START is None:
        _IGNORED_AT_START = frozenset(sig for sig in (*HANDLED, signal.SIGINT)
                                      if signal.getsignal(sig) == signal.SIG_IGN)
    try:
        for sig in (*HANDLED, signal.SIGINT):
            signal.signal(sig, signal.SIG_IGN if sig in _IGNORED_AT_START else _raise)
    except ValueError:   # not the main thread (a study's worker): the process's owner handles signals
        pass


def ignore_signals() -> None:
    """After an interruption: the process is ending, further signals wait for nothing."""
    try:
        for sig in (*HANDLED, signal.SIGINT):
            signal.signal(sig, signal.SIG_IGN)
    except ValueError:
        pass


def exit_status(err: KeyboardInterrupt) -> int:
    """128 + the signal number: 130 for Ctrl-C, 143 for SIGTERM, 129 for SIGHUP, 131 for SIGQUIT."""
    return 128 + getattr(err, "signum", signal.SIGINT)


def signal_name(err: KeyboardInterrupt) -> str:
    return signal.Signals(getattr(err, "signum", signal.SIGINT)).name
