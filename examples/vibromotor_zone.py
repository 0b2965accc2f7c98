"""The vibromotor's contact zone within a period (cases/vibromotor_surface.yaml: a row per node of the
driver's tip, found again as the slider travels): which tip nodes are open, stick or slip at each step of
the last periods, from the run's ``contact_state`` field (0 open, 1 stick, 2 slip), beside the contact's
normal and tangential forces.

A run of 0.01 s (50 periods at 5 kHz) writes its fields every step (``output.format: xdmf``) into a
temporary folder; the last two periods are drawn.

    python examples/vibromotor_zone.py                       # the shares of stick and slip by phase, printed
    python examples/vibromotor_zone.py --plot docs           # and drawn into docs/vibromotor_zone.png
    python examples/vibromotor_zone.py --cell 5e-4           # on a 0.5 mm mesh (meshes/vibromotor.py -h)
    python examples/vibromotor_zone.py --coarse              # 0.004 s (what the test suite runs)
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
from pathlib import Path

import numpy as np

import fem_impact

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "cases" / "vibromotor_surface.yaml"
PERIODS = 2          # drawn: the last ones
TRAVEL = 2e-5        # m: a tip node moves by microns, the slider's face nodes by 0.1 mm in the run


def mesh(folder: Path, cell: float) -> Path:
    spec = importlib.util.spec_from_file_location("vibromotor", ROOT / "meshes" / "vibromotor.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return Path(module.build(folder / f"vibromotor_{cell:g}.msh", cell)["path"])


def zone(cell: float = 1e-3, t_end: float = 0.01) -> dict:
    """The tip nodes' states over the last ``PERIODS`` periods: ``x`` (the tip nodes' positions, m),
    ``phase`` (frames, in periods), ``state`` (frames x nodes), the history's forces there."""
    case = fem_impact.load_case(CASE)
    f = case.parameters["f"]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        run = case.with_changes({"mesh.file": str(mesh(folder, cell)), "solver.t_end": t_end,
                                 "output.vtk": True, "output.format": "xdmf", "output.every": 1})
        result = fem_impact.run(run, folder / "out")
        fields, h = result.fields(), result.history
    t = fields.t
    late = t >= t[-1] - PERIODS / f - 1e-12
    points = fields.points
    states = fields.values["contact_state"].reshape(len(t), -1)
    # The driver's tip: the nodes at the contact's height (where the rows' nodes are) that stayed where
    # they were (the slider's face nodes there, touched by the same rows, travelled with the slider).
    height = points[(states > 0.5).any(axis=0), 1].min()
    top = np.abs(points[:, 1] - height) <= 1e-9
    u = fields.values["u"]
    still = np.abs(u[late][:, :, 0]).max(axis=0) < TRAVEL
    tip = np.flatnonzero(top & still & (points[:, 0] >= -1e-9) & (points[:, 0] <= 0.01 + 1e-9))
    tip = tip[np.argsort(points[tip, 0])]
    expected = round(0.01 / cell) + 1   # (the tip's nodes: 10 mm in cells of ``cell``)
    if tip.size != expected:   # (a slider that did not travel cannot be told from the tip this way)
        raise SystemExit(f"vibromotor_zone: found {tip.size} tip nodes, expected {expected}: the slider's face "
                         f"nodes moved less than {TRAVEL:g} m (a stalled slider?)")
    state = np.rint(states[late][:, tip]).astype(int)
    rows = np.searchsorted(h["t"], t[late] - 1e-12)
    return {"x": points[tip, 0], "t": t[late], "phase": (t[late] - t[late][0]) * f, "state": state,
            "normal": h["drive.force"][rows], "tangential": h["drive.tx"][rows], "f": f,   # (tx: on the tip)
            "speed": float(np.mean(h["slider.px"][h["t"] > t_end / 2]) / result.summary["body_mass"]["slider"])}


def draw(z: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    fig, (forces, states) = plt.subplots(2, 1, figsize=(8, 6), sharex=True, gridspec_kw={"height_ratios": [1, 1.6]})
    forces.plot(z["phase"], z["normal"], color="k", label="normal force N")
    forces.plot(z["phase"], -z["tangential"], color="tab:orange",
                label="friction on the slider along x (-drive.tx)")
    forces.axhline(0.0, color="0.7", lw=0.8)
    forces.set_ylabel("force (N)")
    forces.legend(loc="upper right", fontsize=8)
    forces.set_title(f"vibromotor_surface.yaml: the contact zone over the last {PERIODS} periods "
                     f"(slider at {1e3 * z['speed']:.1f} mm/s)", fontsize=10)
    dx = np.diff(z["x"]).mean() if z["x"].size > 1 else 1e-3
    extent = [z["phase"][0], z["phase"][-1], 1e3 * (z["x"][0] - dx / 2), 1e3 * (z["x"][-1] + dx / 2)]
    cmap = ListedColormap(["white", "tab:blue", "tab:red"])
    states.imshow(z["state"].T, aspect="auto", origin="lower", extent=extent, cmap=cmap, vmin=-0.5, vmax=2.5,
                  interpolation="nearest")
    states.set_xlabel("time within the drive's period (periods)")
    states.set_ylabel("position along the tip (mm)")
    handles = [plt.Rectangle((0, 0), 1, 1, fc=c, ec="0.5") for c in ("white", "tab:blue", "tab:red")]
    states.legend(handles, ["open", "stick", "slip"], loc="upper right", fontsize=8, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def main(coarse: bool = False, plot: Path | None = None, cell: float = 1e-3) -> dict:
    z = zone(cell, 0.004 if coarse else 0.01)
    n = z["state"].shape[1]
    print(f"{n} tip nodes; the slider's mean speed {1e3 * z['speed']:.2f} mm/s")
    print("phase   open  stick  slip   N (N)   friction on the slider, x (N)")
    for k in range(0, len(z["phase"]), 5):
        s = np.bincount(z["state"][k], minlength=3)
        forces = f"{z['normal'][k]:7.2f}  {-z['tangential'][k]:9.3f}"
        print(f"{z['phase'][k]:5.3f}  {s[0]:5d}  {s[1]:5d}  {s[2]:4d}  {forces}")
    stick = (z["state"] == 1).sum() / max((z["state"] > 0).sum(), 1)
    print(f"of the tip nodes in contact, {100 * stick:.1f} % stick over the last {PERIODS} periods")
    if plot:
        draw(z, Path(plot) / "vibromotor_zone.png")
    return z


def cli() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--plot", metavar="FOLDER", type=Path, help="draw FOLDER/vibromotor_zone.png")
    parser.add_argument("--cell", type=float, default=1e-3, help="the mesh's cell size, m (default 1e-3)")
    parser.add_argument("--coarse", action="store_true", help="0.004 s instead of 0.01 s")
    args = parser.parse_args()
    main(args.coarse, args.plot, args.cell)


if __name__ == "__main__":
    cli()
