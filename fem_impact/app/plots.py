"""Plots of a run's history: contact forces, impulses and the energy budget against time."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

ENERGY_TERMS = (
    ("kinetic", "kinetic"), ("strain", "strain"), ("external_work", "external work"),
    ("damping_loss", "damping loss"), ("impact_loss", "impact loss (Carnot)"),
    ("contact_loss", "contact loss (position-level forces)"),
)


class PlotError(ValueError):
    """A history that cannot be plotted (a damaged or foreign history.csv): one line, status 2."""


def read_history(path: Path) -> tuple[list[str], np.ndarray]:
    try:
        with open(path, encoding="utf-8") as f:
            columns = f.readline().strip().split(",")
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise PlotError(f"{path}: cannot read it: {err}") from None
    except ValueError as err:   # a cell that is not a number, a short row
        raise PlotError(f"{path}: not a history that fem-impact wrote: {' '.join(str(err).split())}") from None
    if data.shape[1] != len(columns) and data.size:
        raise PlotError(f"{path}: {len(columns)} column names but {data.shape[1]} values a row")
    return columns, data


def history_columns(outdir: Path) -> dict[str, np.ndarray]:
    """A run's history.csv as columns by their CSV names."""
    columns, data = read_history(Path(outdir) / "history.csv")
    return {name: data[:, i] for i, name in enumerate(columns)}


def plot_history(outdir, png=None, units: dict | None = None) -> Path:
    """Two panels: contact force per contact, and the energy budget with its residual."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..errors import OutputFolderError
    from .outdir.single_file import atomic_file, check_file

    outdir = Path(outdir)
    png = check_file(png if png is not None else outdir / "history.png", protect=[outdir / "history.csv"])
    columns, data = read_history(outdir / "history.csv")
    col = {name: data[:, i] for i, name in enumerate(columns)}
    missing = [c for c in ("t", *(k for k, _ in ENERGY_TERMS), "energy_error") if c not in col]
    if missing or not len(data):
        raise PlotError(f"{outdir / 'history.csv'}: not a run's history (no rows, or no column "
                        f"{', '.join(missing)})")
    fmt = png.suffix.lower().lstrip(".")
    if fmt not in plt.figure().canvas.get_supported_filetypes():
        plt.close("all")
        raise OutputFolderError(f"-o {png}", f"unknown picture format '{fmt}'; write .png, .pdf or .svg")
    plt.close("all")
    t = col["t"]
    units = units or {}
    fig, (ax_f, ax_e) = plt.subplots(2, 1, figsize=(8, 7), sharex=True, constrained_layout=True)
    contacts = [c[: -len(".force")] for c in columns if c.endswith(".force")]
    for name in contacts:
        ax_f.plot(t, col[f"{name}.force"], label=f"{name}: normal force F_N")
    ax_f.set_ylabel(f"contact force {units.get('force', '')}".strip())
    ax_f.legend(loc="upper right")
    ax_f.grid(alpha=0.3)
    e0 = col["kinetic"][0] + col["strain"][0]
    for key, label in ENERGY_TERMS:
        if np.any(col[key]):
            ax_e.plot(t, col[key], label=label)
    ax_e.plot(t, col["kinetic"] + col["strain"], "k", lw=1.5, label="total (kinetic + strain)")
    ax_e.set_ylabel(f"energy {units.get('energy', '')}".strip())
    ax_e.set_xlabel(f"time {units.get('time', '')}".strip())
    # Relative to the energy that flows through the run: the initial energy or the work done.
    scale = max(e0, np.abs(col["external_work"]).max())
    residual = np.abs(col["energy_error"]).max() / scale if scale else 0.0
    ax_e.set_title(f"energy budget (balance residual max {residual:.1e} of the energy scale)", fontsize=10)
    ax_e.legend(loc="center right", fontsize=8)
    ax_e.grid(alpha=0.3)
    summary = outdir / "summary.json"
    try:
        title = json.loads(summary.read_text()).get("case", outdir.name) if summary.is_file() else outdir.name
    except (OSError, ValueError, AttributeError):
        title = outdir.name
    fig.suptitle(str(title))
    with atomic_file(png) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return png


def plot_reduction(runs: dict[str, dict[str, np.ndarray]], u_col: str, png: Path, title: str = "") -> Path:
    """The reduction study in a picture: the probe's displacement and velocity and the total
    contact force of the full model (black) against each reduced run (``runs``: label ->
    history columns; the first is the full model; labels ending in "plain" dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    v_col = u_col.replace(".u", ".v")
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True, constrained_layout=True)
    for k, (label, h) in enumerate(runs.items()):
        style = (dict(color="k", lw=1.6, zorder=3) if k == 0
                 else dict(lw=0.9, ls="--" if label.endswith("plain") else "-"))
        force = sum(h[c] for c in h if c.endswith(".force"))
        for ax, y in zip(axes, (h[u_col], h[v_col], force), strict=True):
            ax.plot(h["t"], y, label=label, **style)
    for ax, name in zip(axes, (f"{u_col} (displacement)", f"{v_col} (velocity)", "total contact force"), strict=True):
        ax.set_ylabel(name, fontsize=9)
        ax.grid(alpha=0.3)
    axes[-1].legend(fontsize=7, loc="upper right")   # (after the last contact: room there, as a rule)
    axes[-1].set_xlabel("time")
    fig.suptitle(title or "reduced models against the full model")
    fig.savefig(png, dpi=100)
    plt.close(fig)
    return png
