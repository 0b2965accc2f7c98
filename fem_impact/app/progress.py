"""The progress bar of every long loop (time loop, sweep runs, animation frames), drawn by tqdm.

A bar is shown on stderr only on an interactive terminal and, under MPI, only on rank 0: a
label, the bar, the percentage, the count and the time left as a person reads it (42.0 s,
12 min, 29 years). Nothing here needs MPI or dolfinx, so light commands can use it too.
"""

from __future__ import annotations

import math
import sys

from tqdm import tqdm


def duration(seconds: float) -> str:
    """A time left as a person reads it: 42.0 s, 12 min, 3.5 h, 250 days, 2.9e+04 years."""
    if not math.isfinite(seconds):
        return "unknown"
    if seconds < 60:
        return f"{seconds:.1f} s"
    if seconds < 3600:
        return f"{seconds / 60:.0f} min"
    if seconds < 86400:
        return f"{seconds / 3600:.1f} h"
    if seconds < 365 * 86400:
        return f"{seconds / 86400:.0f} days"
    return f"{seconds / (365.25 * 86400):.2g} years"


class _Bar(tqdm):
    """tqdm with ``{left}``, the time left through :func:`duration` (tqdm's own ``{remaining}``
    shows a 29-year run as 254040:00:00)."""

    # No monitor thread: the loops call often enough, and a thread would outlive a Ctrl-C.
    monitor_interval = 0

    def __init__(self, *args, clock=None, **kwargs):
        super().__init__(*args, **kwargs)
        if clock is not None:   # (a test's clock: redraws and the time left without waiting)
            self._time = clock
            self.start_t = self.last_print_t = clock()

    @property
    def format_dict(self):
        d = super().format_dict
        # From the mean rate since the start: steps with contact cost more than free flight, and
        # a recent rate would swing with them.
        n, total, elapsed = d["n"], d["total"], d["elapsed"]
        d["left"] = duration(elapsed * (total - n) / n) if n and total else "?"
        return d


class Progress:
    """A one-line progress bar on stderr, only on an interactive terminal and on rank 0.

    Call it as ``progress(step, total)`` after each step; the bar ends its line at
    ``step >= total``. :meth:`end_line` ends an unfinished bar's line (before an error message,
    or after Ctrl-C).

    Parameters
    ----------
    comm : mpi4py.MPI.Comm or None
        The bar shows on its rank 0 only; None for a serial command.
    label : str
        Shown before the bar.
    stream : file-like, optional
        Default ``sys.stderr``.
    unit : str
        What is counted: ``step 450/1000``.
    enabled : bool, optional
        None (default): when ``stream`` is a terminal; True or False to force it (on rank 0).
    clock : callable, optional
        Seconds now, for the redraw interval and the time left; default the wall clock.
    """

    open_bar = None   # the bar whose line is unfinished: end_line() needs no instance

    def __init__(self, comm=None, label: str = "time loop", stream=None, unit: str = "step",
                 enabled: bool | None = None, clock=None):
        self.stream = stream or sys.stderr
        on_rank_0 = comm is None or comm.rank == 0
        self.enabled = on_rank_0 and (self.stream.isatty() if enabled is None else enabled)
        self.label, self.unit, self.clock = label, unit, clock
        self._bar = None

    def __call__(self, step: int, total: int) -> None:
        if not self.enabled:
            return
        if self._bar is None:
            self._bar = _Bar(total=total, desc=self.label, file=self.stream, leave=True, mininterval=0.2,
                             dynamic_ncols=True, clock=self.clock,
                             bar_format="{desc} |{bar}| {percentage:5.1f}% " + self.unit + " {n}/{total} eta {left}")
            Progress.open_bar = self._bar
        self._bar.update(step - self._bar.n)
        if step >= total:
            self.close()

    def close(self) -> None:
        """Draw the bar as it is and end its line."""
        if self._bar is not None:
            _close(self._bar)
            self._bar = None

    @classmethod
    def end_line(cls) -> None:
        """End an unfinished bar's line, so that a message (e.g. interrupted) starts on its own."""
        if cls.open_bar is not None:
            _close(cls.open_bar)


def _close(bar: tqdm) -> None:
    if Progress.open_bar is bar:
        Progress.open_bar = None
    try:
        bar.close()
    except (OSError, ValueError):   # (the terminal may be gone: SIGHUP)
        pass
