"""A response sweep: the impact oscillator's settled response across its period doubling.

    python docs/tutorials/response_sweep.py                                  # six frequencies
    python docs/tutorials/response_sweep.py --values 0.5 0.667 -o /tmp/sweep # two

X'' + X = cos(w t) against a rigid stop with restitution 0.8 (cases/impact_oscillator.yaml: a rod
reduced to its first mode, driven at its tip; docs/impact_oscillator.md derives the closed forms).
Each level flies from impact to impact (``flight="events"``), starts from the previous level's last
state, settles, then samples the stroboscopic Poincare section: period 1 below the period doubling
(w = 2.6533 in the oscillator's time, f = 0.6634 Hz here), period 2 above. The same from the
command line: ``fem-impact study response cases/impact_oscillator.yaml --vary parameters.f=...
--flight events`` (docs/studies.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import fem_impact
from fem_impact.app.studies.response import response_study

CASE = Path(__file__).resolve().parents[2] / "cases" / "impact_oscillator.yaml"


def main(values=(0.45, 0.5, 0.64, 0.66, 0.6645, 0.667), outdir="results/impact_oscillator-response",
         settle: int = 150, periods: int = 8, shooting: bool = True) -> dict:
    case = fem_impact.load_case(CASE)
    study = response_study(case, "parameters.f=" + ",".join(map(str, values)), outdir, settle=settle,
                           periods=periods, flight="events", shooting=shooting, quiet=True)
    by_level: dict[float, list] = {}
    for row in study["rows"]:
        by_level.setdefault(row["parameters.f"], []).append(row)
    for f, rows in by_level.items():
        impulses = ", ".join(f"{r['stop.impulse']:.4f}" for r in rows)
        print(f"f = {f:<7g} period {rows[0]['period']}: impulse per period {impulses}")
    for mark in study["bifurcations"]:
        print(f"{mark['kind']} at f = {mark['parameters.f']:.6g} (between {mark['between']})")
    print(f"response.csv and the bifurcation diagram response.png are in {study['outdir']}")
    return {"periods": {f: rows[0]["period"] for f, rows in by_level.items()}, "study": study}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--values", type=float, nargs="+", default=[0.45, 0.5, 0.64, 0.66, 0.6645, 0.667],
                        help="the drive frequencies in Hz (parameters.f)")
    parser.add_argument("-o", "--outdir", default="results/impact_oscillator-response", help="the study's folder")
    parser.add_argument("--no-shooting", action="store_true", help="no shooting: the sections only (quicker)")
    args = parser.parse_args()
    main(tuple(args.values), args.outdir, shooting=not args.no_shooting)
