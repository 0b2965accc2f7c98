"""The response study's reduced-model side: levels flown event-driven (exact impact instants), and the
period-1 orbit (and longer ones) found by shooting along the sweep, with the bifurcations it shows."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .common import StudyInputError
from .response_period import period_of, section_tolerance

SHOOTING_SECONDS = 300.0     # the time limit of one orbit's shooting
SLOW_SHOOTING = 5.0          # seconds: beyond, shooting says each of Newton's iterations


def _event_levels(cases, key, ordered, freq, direction, settle, periods, tolerance, floor, say):
    """Each level iterates the event-driven Poincare map (fem_impact/periodic/shooting.py): exact impact
    instants instead of a time step's. Returns (rows, ends, candidates): ``ends[v]`` the level's last state."""
    from ...periodic.shooting import ShootingError, impulses, poincare_map, reduced_scene

    rows, ends, candidates, x = [], {}, {}, None
    clock = time.perf_counter()
    for i, v in enumerate(ordered):
        try:
            scene = reduced_scene(cases[v])
        except ShootingError as err:
            raise StudyInputError(f"--flight events: {err}") from None
        x = scene.start if x is None else x
        f = freq[v]
        T = 1.0 / f
        states, kicks = [], []
        try:
            for j in range(settle + periods):
                impacts: list = []
                held = np.zeros(scene.system.P.shape[0])
                x = poincare_map(scene.system, x, T, 1, impacts, held=held)
                if j >= settle:
                    states.append(x.copy())
                    kicks.append((impulses(scene.system, impacts, held), impacts))
        except ShootingError as err:
            raise StudyInputError(f"--flight events at {key}={v:g}: {err}") from None
        states = np.array(states)
        n = scene.system.n
        names = [f"{name}.{kind}{'xyz'[c]}" for name in scene.probes for kind in "uv" for c in range(scene.dim)]
        section = np.zeros((periods, len(names)))
        for j in range(periods):
            u, w = scene.probe_rows @ states[j, :n], scene.probe_rows @ states[j, n:]
            for p, name in enumerate(scene.probes):
                for c in range(scene.dim):
                    section[j, names.index(f"{name}.u{'xyz'[c]}")] = u[p * scene.dim + c]
                    section[j, names.index(f"{name}.v{'xyz'[c]}")] = w[p * scene.dim + c]
        tol = section_tolerance(names, section, 2 * np.pi * f, tolerance, floor)
        k, note, candidates[v] = period_of(section, tol)
        chosen = range(periods - k, periods) if k else range(periods)
        for j in chosen:
            row = {"direction": direction, key: v, "frequency": f, "period": k, "period_note": note,
                   "point": j - chosen.start}
            row.update({name: float(section[j, c]) for c, name in enumerate(names)})
            lam, impacts = kicks[j]
            for name, crows in scene.contacts:
                mine = set(np.arange(lam.size)[crows].tolist())   # (rows: a slice or indices)
                row[f"{name}.impulse"] = float(lam[crows].sum())
                row[f"{name}.impacts"] = sum(1 for _, r, _ in impacts if r in mine)
            rows.append(row)
        ends[v] = x.copy()
        say(f"[{i + 1}/{len(ordered)}] {key}={v:.6g}: period {k}{' (' + note + ')' if note else ''} "
            f"({settle + periods} periods at {f:.6g} Hz, event-driven; elapsed {time.perf_counter() - clock:.1f} s)")
    return rows, ends, candidates


def _end_state(end):
    """A level's last state [Z, Z']: the event-driven sweep's, or the time-stepped run's checkpoint."""
    if isinstance(end, np.ndarray):
        return end
    import h5py

    with h5py.File(Path(end) / "checkpoint" / "rank-0.h5", "r") as f:
        return np.concatenate([f["integrator"]["U"][()], f["integrator"]["V"][()]])


def shoot_branch(cases, key, ordered, freq, ends, rows, seconds=SHOOTING_SECONDS, say=None,
                 candidates=None) -> tuple[dict, str]:
    """Along the sweep: the period-1 orbit by shooting, continued from level to level (from the previous
    orbit, else the level's last state), and the settled response's own period where it is longer (or
    the periods an unresolved section leaves open). Per level the columns response.csv adds; (orbits,
    "done") or ({}, "not done: why")."""
    from ...periodic.shooting import ShootingError, impulses, least_period, reduced_scene, shoot

    say = say or (lambda line: None)
    clock = time.perf_counter()
    periods, candidates = {}, candidates or {}
    for row in rows:
        periods[row[key]] = row["period"]
    out, previous = {}, None
    for v in ordered:
        if v not in ends:
            continue
        try:
            scene = reduced_scene(cases[v])
        except ShootingError as err:
            return {}, f"not done: {err}"
        T = 1.0 / freq[v]
        last = _end_state(ends[v])
        info, said = {}, []
        for k in sorted({1, periods.get(v, 0), *candidates.get(v, [])} - {0}):
            def progress(iteration, residual, elapsed, k=k):   # (a line per iteration once it takes a while)
                if elapsed > SLOW_SHOOTING:
                    say(f"  shooting the period-{k} orbit at {key}={v:.6g}: Newton iteration {iteration}, residual "
                        f"{residual:.3g} of the state's scale ({elapsed:.0f} s, limit {seconds:g} s)")

            start = previous if (k == 1 and previous is not None) else last
            try:
                orbit = shoot(scene.system, start, T, k, seconds=seconds, progress=progress)
                if k == 1 and previous is not None and orbit.residual > 1e-6:
                    raise ShootingError("no convergence from the previous orbit")
            except ShootingError as first:
                if start is last:
                    info[f"orbit{k}.note"] = str(first)
                    said.append(f"period {k}: none ({first})")
                    continue
                try:
                    orbit = shoot(scene.system, last, T, k, seconds=seconds, progress=progress)
                except ShootingError as err:
                    info[f"orbit{k}.note"] = str(err)
                    said.append(f"period {k}: none ({err})")
                    continue
            if k > 1:
                try:
                    m = least_period(scene.system, orbit, T, seconds)
                except ShootingError as err:
                    m, why = None, str(err)
                if m != k:
                    info[f"orbit{k}.note"] = (f"the orbit found is the period-{m} orbit" if m else
                                              f"its least period is not known: {why}")
                    said.append(f"period {k}: " + (f"the period-{m} orbit" if m else "least period not known"))
                    continue
            mu = orbit.multipliers[np.argsort(-np.abs(orbit.multipliers))]
            info[f"orbit{k}.residual"] = orbit.residual
            info[f"orbit{k}.stable"] = int(orbit.stable)
            info[f"orbit{k}.impulse"] = float(impulses(scene.system, orbit.impacts, orbit.held).sum()) / k
            info[f"orbit{k}.impacts"] = len(orbit.impacts)
            info[f"orbit{k}.min_speed"] = min((s for _, _, s in orbit.impacts), default=0.0)
            for i, m in enumerate(mu[:4], start=1):
                info[f"orbit{k}.multiplier{i}.re"] = float(m.real)
                info[f"orbit{k}.multiplier{i}.im"] = float(m.imag)
            info[f"orbit{k}.det_plus"] = float(np.prod(1.0 + orbit.multipliers).real)    # 0: a multiplier at -1
            info[f"orbit{k}.det_minus"] = float(np.prod(1.0 - orbit.multipliers).real)   # 0: a multiplier at +1
            if orbit.unseen:
                info[f"orbit{k}.unseen_modes"] = orbit.unseen
            if k == 1:
                previous = orbit.x
            said.append(f"period {k}: {'stable' if orbit.stable else 'unstable'} ({orbit.iterations} iterations)")
        out[v] = info
        say(f"shooting at {key}={v:.6g}: " + "; ".join(said) + f" (elapsed {time.perf_counter() - clock:.1f} s)")
    return out, "done"


def find_bifurcations(key, ordered, orbits) -> list[dict]:
    """Where the period-1 orbit's multipliers cross -1 (period doubling: prod(1 + mu) changes sign) or +1
    (saddle-node: prod(1 - mu)), between two levels of the sweep, the value interpolated linearly;
    and grazing, where its slowest impact's speed falls to zero or shooting loses it."""
    found = []
    known = [(f, orbits[f]) for f in ordered if f in orbits and "orbit1.det_plus" in orbits[f]]
    for (f0, a), (f1, b) in zip(known, known[1:]):
        for name, column in (("period_doubling", "orbit1.det_plus"), ("saddle_node", "orbit1.det_minus")):
            g0, g1 = a[column], b[column]
            if g0 * g1 < 0:
                found.append({"kind": name, key: f0 + (f1 - f0) * g0 / (g0 - g1), "between": [f0, f1]})
    for f in ordered:
        info = orbits.get(f, {})
        if "orbit1.note" in info and "vanishing speed" in info["orbit1.note"]:
            found.append({"kind": "grazing", key: f, "between": [f, f]})
    return found
