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


def read_history(path: Path) -> tuple[list[str], np.ndarray]:
    with open(path) as f:
        columns = f.readline().strip().split(",")
    return columns, np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def history_columns(outdir: Path) -> dict[str, np.ndarray]:
    """A run's history.csv as columns by their CSV names."""
    columns, data = read_history(Path(outdir) / "history.csv")
    return {name: data[:, i] for i, name in enumerate(columns)}


def plot_history(outdir, png=None, units: dict | None = None) -> Path:
    """Two panels: contact force per contact, and the energy budget with its residual."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    outdir = Path(outdir)
    png = Path(png) if png else outdir / "history.png"
    columns, data = read_history(outdir / "history.csv")
    col = {name: data[:, i] for i, name in enumerate(columns)}
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
    fig.suptitle(json.loads(summary.read_text()).get("case", outdir.name) if summary.is_file() else outdir.name)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png
