"""A shaken table: a ball's impact phase and period doubling, and a part carried by a vibratory conveyor.

    python docs/tutorials/shaken_table.py                 # the ball, its sweep over Gamma, the conveyor
    python docs/tutorials/shaken_table.py -o /tmp/table   # elsewhere

cases/bouncing_ball.yaml: a ball (a rod reduced to its rigid mode) on a table that is an obstacle given a
motion, A sin(w t + phi - pi) at 50 Hz, Gamma = A w^2 / g = 1.3, e = 0.5: its impacts settle on the
period-1 orbit, at the table's phase phi = acos(pi (1 - e) / ((1 + e) Gamma)), which the shifted motion
puts at T/2 (impacts.csv's phase 1/2; periods.csv a row per period). The response study over Gamma at the
fixed drive frequency, with event-driven flights, finds the period doubling at the closed form's
sqrt((pi (1 - e) / (1 + e))^2 + (2 (1 + e^2) / (1 + e)^2)^2). cases/vibratory_conveyor.yaml: a part on an
obliquely shaken tray, here rigid (``bodies``), carried at its mean speed per period.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import fem_impact
from fem_impact.app.studies.response import response_study

CASES = Path(__file__).resolve().parents[2] / "cases"


def rows_of(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def main(outdir="results/shaken_table", t_end: float = 0.4, gammas=(1.3, 1.5, 1.55),
         conveyor_periods: int = 10) -> dict:
    outdir = Path(outdir)
    e, gamma = 0.5, 1.3
    phi = math.degrees(math.acos(math.pi * (1 - e) / ((1 + e) * gamma)))
    ball = fem_impact.run(fem_impact.load_case(CASES / "bouncing_ball.yaml", [f"solver.t_end={t_end}"]),
                          outdir / "ball")
    impacts = rows_of(ball.outdir / "impacts.csv")
    last = impacts[-1]
    print(f"ball: {len(impacts)} impacts; the last at t = {float(last['t_contact']):.6f} s, phase "
          f"{float(last['phase']):.4f} of the period (the orbit's: 0.5, the table at {phi:.2f} deg)")
    periods = rows_of(ball.outdir / "periods.csv")
    p = periods[-1]
    print(f"its last period: {p['table.impacts']} impact, mean velocity {float(p['bar.vx_mean']):.2e} m/s, "
          f"the table's work {float(p['external_work']):.4e} J against the losses {float(p['losses']):.4e} J")
    study = response_study(fem_impact.load_case(CASES / "bouncing_ball.yaml"),
                           "parameters.Gamma=" + ",".join(map(str, gammas)), outdir / "sweep", settle=300,
                           periods=4, flight="events", frequency="f", quiet=True)
    found = {row["parameters.Gamma"]: row["period"] for row in study["rows"]}
    print("period by Gamma: " + ", ".join(f"{g:g}: {k}" for g, k in found.items()))
    closed = math.sqrt((math.pi * (1 - e) / (1 + e)) ** 2 + (2 * (1 + e * e) / (1 + e) ** 2) ** 2)
    for mark in study["bifurcations"]:
        print(f"{mark['kind']} at Gamma = {mark['parameters.Gamma']:.6f} (closed form {closed:.6f})")
    conveyor = fem_impact.run(fem_impact.load_case(CASES / "vibratory_conveyor.yaml", [
        "bodies={bar: {model: rigid}}", "solver.dt=1.25e-4", f"solver.t_end={conveyor_periods / 20}",
        "output.vtk=false"]), outdir / "conveyor")
    speeds = [float(row["bar.vx_mean"]) for row in rows_of(conveyor.outdir / "periods.csv")]
    print("conveyor, mean speed per period (m/s): " + ", ".join(f"{v:.5f}" for v in speeds))
    return {"phase": float(last["phase"]), "periods": found, "marks": study["bifurcations"], "speeds": speeds,
            "ball": ball, "conveyor": conveyor}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--outdir", default="results/shaken_table", help="the results' folder")
    main(parser.parse_args().outdir)
