"""What a response sweep writes and says: response.csv (both directions of the folder), study.json,
response-DIRECTION.json, the bifurcation diagram response.png, and the table printed at the end."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..outdir.writes import replacing
from .common import case_record, pyplot, save_figure, write_json
from .response_orbits import find_bifurcations

DIRECTIONS = ("up", "down")


def _finish(case, changes, outdir, key, expression, ordered, freq, direction, settings, rows, orbits, note, other,
            outcomes):
    """response.csv, study.json, response-DIRECTION.json, response.png (both directions of the folder)."""
    bifurcations = find_bifurcations(key, ordered, orbits)
    for row in rows:   # response.csv says where: on the rows of the level past each crossing
        marks = [f"{b['kind']} at {b[key]:.6g}" for b in bifurcations if b["between"][1] == row[key]]
        if bifurcations:
            row["bifurcation"] = "; ".join(marks)
    outdir.mkdir(parents=True, exist_ok=True)   # (the event-driven levels write no level folder)
    theirs = [r for r in other.get("rows", []) if isinstance(r, dict) and key in r]
    all_rows = sorted(theirs + rows, key=lambda r: (r["direction"], r[key], r["point"]))
    columns = list(dict.fromkeys(c for r in all_rows for c in r)) if all_rows else \
        ["direction", key, "frequency", "period", "period_note", "point"]
    _write_rows(outdir / "response.csv", columns, all_rows)
    sweep = {"values": ordered, "frequencies": [freq[v] for v in ordered], "shooting": note,
             "bifurcations": bifurcations, "settings": settings,
             "levels": {o.level.info["value"]: o.status for o in outcomes} if outcomes else None}
    write_json(outdir / f"response-{direction}.json", {**sweep, "rows": rows})
    sweeps = {direction: {k: v for k, v in sweep.items() if k != "settings"}}
    if other:
        sweeps[DIRECTIONS[1 - DIRECTIONS.index(direction)]] = {k: other.get(k) for k in sweep if k != "settings"}
    s = settings
    write_json(outdir / "study.json", {"study": "response", "vary": key, "frequency": expression,
                                       "settle": s["settle"], "periods": s["periods"],
                                       "steps_per_period": s["steps_per_period"], "tolerance": s["tolerance"],
                                       "flight": s["flight"], "sweeps": sweeps, "direction": direction,
                                       "values": ordered, "shooting": note,
                                       f"bifurcations_{direction}": bifurcations,
                                       **({f"bifurcations_{d}": sweeps[d].get("bifurcations") or []
                                           for d in sweeps if d != direction}),
                                       **case_record(case, changes)})
    marks = bifurcations + list(other.get("bifurcations") or [])
    frequency_axis = key == f"parameters.{expression}"
    chart = plot_response(all_rows, key, outdir / "response.png", marks, frequency_axis) if all_rows else None
    missing = [(direction, o.level.info["value"], "FAILED: " + o.reason if o.status == "failed" else
                "not run: a level before it failed, and each level starts from the one before")
               for o in outcomes if not o.ok]
    return {"rows": all_rows, "key": key, "frequency": expression, "levels": list(outcomes), "chart": chart,
            "outdir": str(outdir), "bifurcations": bifurcations, "shooting": note, "missing": missing}


def _write_rows(path: Path, columns, rows) -> None:
    with replacing(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: f"{v:.12g}" if isinstance(v, float) else v for k, v in row.items()})


def plot_response(rows: list[dict], key: str, path: Path, marks=(), frequency_axis: bool = True) -> Path:
    plt = pyplot()
    probe = next((c for c in rows[0] if c.endswith((".ux", ".uy", ".uz"))), None)
    contacts = [c[: -len(".impulse")] for c in rows[0] if c.endswith(".impulse") and not c.startswith("orbit")]
    fig, axes = plt.subplots(2 if contacts else 1, 1, figsize=(8, 7 if contacts else 4), sharex=True, squeeze=False)
    colours = {"up": "tab:blue", "down": "tab:red"}
    for direction in DIRECTIONS:
        mine = [r for r in rows if r["direction"] == direction]
        if not mine:
            continue
        x = np.array([r[key] for r in mine])
        if probe is not None:
            axes[0, 0].plot(x, [r[probe] for r in mine], ".", ms=4, color=colours[direction],
                            label=f"sweep {direction}")
        if contacts:
            for c in contacts:
                axes[1, 0].plot(x, [r[f"{c}.impulse"] for r in mine], ".", ms=4, color=colours[direction],
                                label=f"{c}, sweep {direction}")
        if contacts and any("orbit1.impulse" in r for r in mine):   # the period-1 orbit from shooting
            orbit = sorted({r[key]: r for r in mine if "orbit1.impulse" in r}.values(), key=lambda r: r[key])
            stable = np.array([r["orbit1.stable"] for r in orbit], dtype=bool)
            xs, ys = np.array([r[key] for r in orbit]), np.array([r["orbit1.impulse"] for r in orbit])
            axes[1, 0].plot(xs[stable], ys[stable], "o", mfc="none", ms=7, color="k",
                            label="period-1 orbit (shooting), stable" if direction == "up" else None)
            axes[1, 0].plot(xs[~stable], ys[~stable], "x", ms=7, color="k",
                            label="period-1 orbit (shooting), unstable" if direction == "up" else None)
    for mark in marks:
        for ax in axes[:, 0]:
            ax.axvline(mark[key], ls="--", lw=0.8, color="tab:green" if mark["kind"] == "period_doubling"
                       else "tab:orange" if mark["kind"] == "saddle_node" else "tab:gray")
        axes[0, 0].annotate(mark["kind"].replace("_", " "), (mark[key], 1.0), xycoords=("data", "axes fraction"),
                            rotation=90, va="top", ha="right", fontsize=7)
    axes[0, 0].set_ylabel(f"{probe} at forcing phase 0" if probe else "")
    axes[0, 0].set_title("Bifurcation diagram: the stroboscopic Poincare section of the settled response")
    if axes[0, 0].get_legend_handles_labels()[0]:   # (no probe: nothing drawn there to name)
        axes[0, 0].legend(loc="best", fontsize=8)
    if contacts:
        axes[1, 0].set_ylabel("impulse per forcing period")
        axes[1, 0].legend(loc="best", fontsize=8)
    axes[-1, 0].set_xlabel(f"{key} (forcing frequency, Hz)" if frequency_axis else key)
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def format_response(result: dict) -> str:
    """The table printed at the end: per level the period found (``?``: not resolved) and the impulses."""
    key = result["key"]
    frequency = result.get("frequency")
    own = frequency is None or key == f"parameters.{frequency}"
    lines = [f"{'direction':<9} {key:>14} " + ("" if own else f"{'Hz':>10} ") +
             f"{'period':>6} {'points':>6}  impulse per period"]
    seen, notes = {}, []
    for r in result["rows"]:
        seen.setdefault((r["direction"], r[key]), []).append(r)
    for (direction, value), rows in sorted(seen.items()):
        names = [k for k in rows[0] if k.endswith(".impulse") and not k.startswith("orbit")]
        per = ", ".join(f"{np.mean([r[k] for r in rows]):.4g}" for k in names)
        note = rows[0].get("period_note") or ""
        period = "?" if note.startswith("not resolved") else rows[0]["period"]
        hz = "" if own else f"{rows[0].get('frequency', float('nan')):>10.6g} "
        lines.append(f"{direction:<9} {value:>14.6g} {hz}{period:>6} {len(rows):>6}  {per}")
        if period == "?":
            notes.append(f"{direction} {key}={value:.6g}: period {note}")
    lines += notes
    lines += [f"{direction} {key}={value:.6g}: {why}" for direction, value, why in result.get("missing", [])]
    for mark in result.get("bifurcations", []):
        lines.append(f"{mark['kind'].replace('_', ' ')} at {key} = {mark[key]:.6g} (between {mark['between'][0]:.6g} "
                     f"and {mark['between'][1]:.6g})")
    if result.get("shooting") not in (None, "done"):
        lines.append(f"shooting {result['shooting']}")
    lines.append(f"response.csv, response.png in {result['outdir']}")
    return "\n".join(lines)
