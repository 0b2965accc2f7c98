"""The friction drive of cases/vibromotor.yaml, characterised: the slider's steady speed against the load
(the motor characteristic, from no load to stall), against the drive frequency and against the
preload; the stick and slip phases within a period; the speed's convergence in mesh and step.

Each point is a run in memory (nothing written) of 0.01 s (50 periods at 5 kHz); the speed is the
slider's mean over the second half (the regime is periodic after a few periods).

    python examples/vibromotor_curves.py                    # the curves, printed
    python examples/vibromotor_curves.py --plot docs        # and drawn into docs/vibromotor_characteristic.png, docs/vibromotor_period.png
    python examples/vibromotor_curves.py --convergence      # the unloaded speed at h/2 and dt/2 too
    python examples/vibromotor_curves.py --coarse           # three loads only (what the test suite runs)
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import fem_impact

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "cases" / "vibromotor.yaml"
MU = 0.3


def speed(case: fem_impact.Case, changes: dict) -> tuple[float, dict]:
    """The slider's mean speed over the second half of a 0.01 s run, and the history."""
    run = case.with_changes({"solver.t_end": 0.01, "output.vtk": False, **changes})
    result = fem_impact.run(run)
    h = result.history
    h["slider.vx"] = h["slider.px"] / result.summary["body_mass"]["slider"]
    late = h["t"] > 0.005
    return float(h["slider.vx"][late].mean()), h


def stall(loads, speeds) -> float:
    """The load where the speed crosses zero (linear between the two points around it)."""
    for (f0, v0), (f1, v1) in zip(zip(loads, speeds), zip(loads[1:], speeds[1:])):
        if v0 > 0.0 >= v1:
            return f0 + (f1 - f0) * v0 / (v0 - v1)
    return float("nan")


def main(coarse: bool = False, plot: Path | None = None, convergence: bool = False) -> dict:
    case = fem_impact.load_case(CASE)
    loads = [0.0, 2.0, 4.0] if coarse else [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0]
    speeds = [speed(case, {"parameters.FL": f})[0] for f in loads]
    out = {"loads": loads, "speeds": speeds, "stall": stall(loads, speeds)}
    print("load (N)  speed (mm/s)")
    for f, v in zip(loads, speeds):
        print(f"{f:8.2f}  {1e3 * v:11.3f}")
    print(f"stall force {out['stall']:.3f} N (mu P = {MU * 20.0:.1f} N)")
    if not coarse:
        out["frequencies"] = [3000.0, 4000.0, 5000.0, 6000.0, 7000.0]
        out["by_frequency"] = [speed(case, {"parameters.FL": 0.0, "parameters.f": f, "solver.dt": 1.0 / (40 * f)})[0]
                               for f in out["frequencies"]]
        out["preloads"] = [10.0, 15.0, 20.0, 25.0, 30.0]
        out["by_preload"] = [speed(case, {"parameters.FL": 0.0, "parameters.P": p})[0] for p in out["preloads"]]
        print("f (Hz)  unloaded speed (mm/s):", ", ".join(f"{f:.0f}: {1e3 * v:.2f}"
                                                   for f, v in zip(out["frequencies"], out["by_frequency"])))
        print("P (N)   unloaded speed (mm/s):", ", ".join(f"{p:.0f}: {1e3 * v:.2f}"
                                                   for p, v in zip(out["preloads"], out["by_preload"])))
    if convergence:
        out["convergence"] = converge(case)
    if plot is not None:
        draw(case, out, Path(plot))
    return out


def converge(case: fem_impact.Case) -> dict:
    """The unloaded and the 2 N speeds at the case's mesh and step, at dt/2, and on a mesh of h/2."""
    rows = {}
    for label, changes in (("h = 1 mm, dt = T/40", {}), ("dt = T/80", {"solver.dt": 2.5e-6})):
        rows[label] = [speed(case, {"parameters.FL": f, **changes})[0] for f in (0.0, 2.0)]
    with tempfile.TemporaryDirectory() as folder:
        mesh = Path(folder) / "fine.msh"
        subprocess.run([sys.executable, str(ROOT / "meshes" / "vibromotor.py"), "-h", "5e-4", "-o", str(mesh)],
                       check=True)
        rows["h = 0.5 mm"] = [speed(case, {"parameters.FL": f, "mesh.file": str(mesh)})[0] for f in (0.0, 2.0)]
    for label, (v0, v2) in rows.items():
        print(f"{label:22s} unloaded {1e3 * v0:.3f} mm/s, at 2 N {1e3 * v2:.3f} mm/s")
    return rows


def draw(case: fem_impact.Case, out: dict, folder: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), constrained_layout=True)
    axes[0].plot(out["loads"], 1e3 * np.array(out["speeds"]), "o-")
    axes[0].axhline(0.0, color="0.6", lw=0.8)
    axes[0].set(xlabel="load F_L (N)", ylabel="slider speed (mm/s)",
                title=f"characteristic (stall {out['stall']:.2f} N)")
    axes[1].plot(np.array(out["frequencies"]) / 1e3, 1e3 * np.array(out["by_frequency"]), "o-")
    axes[1].set(xlabel="drive frequency f (kHz)", ylabel="unloaded speed (mm/s)", title="against frequency")
    axes[2].plot(out["preloads"], 1e3 * np.array(out["by_preload"]), "o-")
    axes[2].set(xlabel="preload P (N)", ylabel="unloaded speed (mm/s)", title="against preload")
    fig.savefig(folder / "vibromotor_characteristic.png", dpi=110)
    plt.close(fig)

    # Stick and slip within a period, at 2 N (the last period of the run).
    _, h = speed(case, {"parameters.FL": 2.0})
    t = h["t"]
    period = t > t[-1] - 2e-4
    tt = 1e6 * (t[period] - t[period][0])
    fig, ax = plt.subplots(2, 1, figsize=(7, 5), sharex=True, constrained_layout=True)
    ax[0].plot(tt, h["drive.force"][period], label="normal force N")
    ax[0].plot(tt, -h["drive.tx"][period], label="thrust on the slider")
    ax[0].plot(tt, MU * h["drive.force"][period], ":", color="0.4", label="mu N")
    ax[0].plot(tt, -MU * h["drive.force"][period], ":", color="0.4")
    ax[0].set(ylabel="force (N)", title="F_L = 2 N: the last period")
    ax[0].legend(fontsize=8)
    ax[1].plot(tt, 1e3 * h["tip.vx"][period], label="driver tip (probe) v_x")
    ax[1].plot(tt, 1e3 * h["slider.vx"][period], label="slider v_x")
    stuck = h["drive.sticking"][period] > 0
    ax[1].fill_between(tt, 0, 1, where=stuck, transform=ax[1].get_xaxis_transform(), color="C2", alpha=0.2,
                       label="sticking")
    ax[1].set(xlabel="time in the period (us)", ylabel="velocity (mm/s)")
    ax[1].legend(fontsize=8)
    fig.savefig(folder / "vibromotor_period.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    args = sys.argv[1:]
    target = Path(args[args.index("--plot") + 1]) if "--plot" in args else None
    main(coarse="--coarse" in args, plot=target, convergence="--convergence" in args)
