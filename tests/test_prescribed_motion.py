"""Prescribed motion of supports (supports[].displacement; fem_impact/fem/prescribed.py, docs/theory.md s. 2.4).

A rod at rest against a wall, its other end pushed at a constant speed v: the compression wave
rho c A v starts at the pushed end, doubles on the wall (t = L/c), doubles again on the pushed end,
whose velocity is held (t = 2L/c), and reaches the wall as 4 rho c A v at t = 3L/c. The wall
force is the staircase 0, 2 rho c A v, 4 rho c A v on [0, L/c], [L/c, 3L/c], [3L/c, 5L/c]; the
pushed end's reaction is rho c A v, 3 rho c A v, 5 rho c A v on [0, 2L/c], [2L/c, 4L/c], [4L/c, 5L/c].
"""

from __future__ import annotations

import numpy as np
import pytest

import fem_impact as fi
from fem_impact.config.case import CaseError
from fem_impact.errors import SimulationError

from conftest import CASES

V = 0.01          # pushing speed (E = rho = A = L = 1: c = 1, rho c A v = V)
CELLS = 200
METHODS = {
    "moreau_jean": {},
    "newmark": {},
    "central_difference": {"mass": "lumped"},
    "modal": {"modes": 40, "static_correction": True},
}


def pushed_rod(method: str, end: str = "left", **solver):
    """The rod pushed at its ``end``, the wall at the other; the mirror (``end="right"``) pushed in -x."""
    sign, wall = (1.0, "right") if end == "left" else (-1.0, "left")
    data = {"name": "pushed", "parameters": {"v": sign * V},
            "mesh": {"shape": "bar", "dim": 1, "length": 1.0, "cells": CELLS},
            "material": {"E": 1.0, "rho": 1.0, "nu": 0.0, "area": 1.0},
            "supports": [{"nodes": end, "fix": ["x"], "displacement": ["v*t"]}],
            "contacts": [{"name": "wall", "type": "obstacle", "nodes": wall, "normal": [sign], "gap": 0.0}],
            "solver": {"method": method, "dt": 0.5 / CELLS, "t_end": 5.0, **METHODS[method], **solver},
            "output": {"vtk": False, "probes": {"base": [0.0 if end == "left" else 1.0],
                                                "tip": [1.0 if end == "left" else 0.0]}}}
    return fi.run(fi.Case.from_dict(data)).history


def plateau(h, column, start, end):
    t = h["t"]
    return np.median(h[column][(t > start + 0.2) & (t < end - 0.1)])


def support_work(h, column, velocity):
    """The work of the support's reaction on its prescribed velocity, by the trapezoidal rule."""
    power = h[column] * velocity
    return np.concatenate([[0.0], np.cumsum(0.5 * np.diff(h["t"]) * (power[1:] + power[:-1]))])


@pytest.mark.parametrize("end", ["left", "right"])
@pytest.mark.parametrize("method", list(METHODS))
def test_a_rod_pushed_against_a_wall_gives_the_staircase_force_in_every_method(method, end):
    """Pushed at either end: whether a contact is taken must not depend on how the dofs are numbered."""
    h = pushed_rod(method, end)
    sign = 1.0 if end == "left" else -1.0
    for (start, stop), level in zip(((0.0, 1.0), (1.0, 3.0), (3.0, 5.0)), (0.0, 2 * V, 4 * V)):
        assert plateau(h, "wall.force", start, stop) == pytest.approx(level, rel=0.01, abs=1e-6 * V)
    for (start, stop), level in zip(((0.0, 2.0), (2.0, 4.0), (4.0, 5.0)), (V, 3 * V, 5 * V)):
        assert sign * plateau(h, f"{end}.reaction", start, stop) == pytest.approx(level, rel=0.01)
    # the pushed end follows its prescribed motion; the wall holds the other
    assert h["base.ux"][-1] == pytest.approx(sign * V * 5.0, rel=1e-12)
    assert h["base.vx"][-1] == pytest.approx(sign * V, rel=1e-12)
    assert h["wall.gap"].min() >= -1e-12 * V
    assert abs(h["tip.ux"]).max() <= 5 * V * 0.5 / CELLS   # (the mesh's ripple ahead of the front: 3 v dt)
    # The energy budget closes with the support's work as external work, and that work is the
    # reaction's on the prescribed velocity; nothing is created.
    # (central difference conserves kinetic + strain plus its own term, -dt^2/8 A.M A)
    energy = h["kinetic"] + h["strain"] + h.get("scheme_energy", 0.0)
    scale = energy.max()
    assert np.abs(h["energy_error"]).max() <= 1e-9 * scale
    assert np.abs(h["external_work"] - support_work(h, f"{end}.reaction", sign * V)).max() <= 2e-3 * scale
    assert (energy - energy[0] - h["external_work"]).max() <= 1e-8 * scale
    assert min(h["impact_loss"].min(), h["contact_loss"].min()) >= -1e-8 * scale


def beam(method: str, periods: int = 8, **changes):
    overrides = [f"solver.t_end={periods / 2.7}", "output.vtk=false", f"solver.method={method}"]
    if method == "modal":
        overrides += ["solver.modes=10"]
    overrides += [f"{key}={value}" for key, value in changes.items()]
    return fi.run(fi.load_case(CASES / "base_excited_beam.yaml", overrides=overrides)).history


def impulse_per_period(h, f=2.7, periods=8):
    k = np.floor(h["t"][1:] * f * (1 - 1e-12)).astype(int)
    return np.bincount(k, weights=h["stop.impulse"][1:], minlength=periods)[:periods]


@pytest.mark.slow   # (20 s: the reduced model's moving supports stay in the default tier through tests/test_restart.py)
def test_a_base_excited_cantilever_hits_its_stop_alike_in_the_full_and_the_reduced_model():
    """The clamp shaken at 2.7 Hz (first bending mode 2.80 Hz) by 20 um; the tip on an elastic stop
    0.1 mm away. The reduced model (10 fixed-base modes and the static correction, which holds the
    clamp's quasi-static motion) gives the full model's impulse per period within 1 %."""
    full, reduced = beam("moreau_jean"), beam("modal")
    a, b = impulse_per_period(full), impulse_per_period(reduced)
    assert np.count_nonzero(a > 0.05 * a.max()) >= 5          # the tip hits the stop in most periods
    assert np.abs(b - a).max() <= 0.01 * a.max()
    for h in (full, reduced):
        energy = h["kinetic"] + h["strain"]
        assert np.abs(h["energy_error"]).max() <= 1e-9 * energy.max()
        assert (energy - energy[0] - h["external_work"]).max() <= 1e-9 * energy.max()
        # the clamp's work is its reaction's on the prescribed velocity
        velocity = 2e-5 * 2 * np.pi * 2.7 * np.cos(2 * np.pi * 2.7 * h["t"])
        assert np.abs(h["external_work"] - support_work(h, "left.reaction_y", velocity)).max() <= 0.01 * energy.max()


def test_with_damping_the_support_pays_what_damping_and_the_stop_take():
    """alpha and beta damping, full model: the balance closes, the damping loss grows step by step,
    and the clamp's work from the balance is its reaction's on its velocity (to the time step's order)."""
    h = beam("newmark", periods=4, **{"damping.alpha": 0.5, "damping.beta": 1e-4})
    energy = h["kinetic"] + h["strain"]
    assert np.abs(h["energy_error"]).max() <= 1e-9 * energy.max()
    assert np.diff(h["damping_loss"]).min() >= -1e-12 * energy.max()
    assert (energy - energy[0] - h["external_work"]).max() <= 1e-9 * energy.max()
    velocity = 2e-5 * 2 * np.pi * 2.7 * np.cos(2 * np.pi * 2.7 * h["t"])
    assert h["external_work"][-1] == pytest.approx(support_work(h, "left.reaction_y", velocity)[-1], rel=1e-3)
    with pytest.raises(CaseError, match="damping.beta: the reduced model with a moving support"):
        beam("modal", periods=1, **{"damping.beta": 1e-4})


def test_prescribed_motion_is_checked():
    base = {"name": "m", "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.1, "cells": 10},
            "material": {"E": 1.0, "rho": 1.0}, "solver": {"dt": 0.01, "t_end": 0.02}, "output": {"vtk": False}}

    def case(supports, contacts=()):
        return fi.Case.from_dict({**base, "supports": supports, "contacts": list(contacts)})

    with pytest.raises(CaseError, match=r"supports\[0\].displacement: gives 1 expressions for the 2 fixed"):
        case([{"nodes": "left", "fix": ["x", "y"], "displacement": ["t"]}])
    with pytest.raises(CaseError, match=r"supports\[0\].displacement\[0\]: .*'x' is not an allowed name"):
        case([{"nodes": "left", "fix": ["x"], "displacement": ["x*t"]}])
    on_moving = case([{"nodes": "left", "fix": ["x"], "displacement": ["0.01*t"]}],
                     [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0, 0.0], "gap": 0.1}])
    with pytest.raises(CaseError, match=r"contacts\[0\].nodes: acts on nodes whose motion a support prescribes"):
        fi.run(on_moving)
    blowing_up = case([{"nodes": "left", "fix": ["x"], "displacement": ["1/(0.01 - t)"]}])
    with pytest.raises(SimulationError, match="support's motion '1/\\(0.01 - t\\)'.* no longer finite"):
        fi.run(blowing_up)
    # fix in any order: the expressions follow it
    swapped = case([{"nodes": "left", "fix": ["y", "x"], "displacement": ["0.5*t", "0"]}])
    h = fi.run(swapped.with_changes({"output.probes": {"corner": [0.0, 0.0]}})).history
    assert h["corner.uy"][-1] == pytest.approx(0.5 * h["t"][-1], rel=1e-12)
    assert h["corner.ux"][-1] == 0.0 and h["corner.vy"][-1] == pytest.approx(0.5, rel=1e-12)
    assert "left.reaction_x" in h and "left.reaction_y" in h


def _plate(supports, **solver):
    return {"name": "m", "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.1, "cells": 10},
            "material": {"E": 1.0, "rho": 1.0}, "supports": supports,
            "solver": {"dt": 0.01, "t_end": 0.02, **solver}, "output": {"vtk": False}}


def test_the_reduced_model_without_static_correction_refuses_a_moving_support():
    """Its fixed-base modes alone would leave the support's quasi-static motion out (the structure
    staying behind its support): refused before anything is built, naming the key."""
    moving = [{"nodes": "left", "fix": ["x", "y"], "displacement": ["0", "1e-4*sin(30*t)"]}]
    for scheme in ("moreau_jean", "newmark"):
        with pytest.raises(CaseError, match=r"solver.static_correction: supports\[0\] moves"):
            fi.Case.from_dict(_plate(moving, method="modal", scheme=scheme, modes=3, static_correction=False))
    # a motion that is the constant 0 holds still: the truncated model takes it
    still = [{"nodes": "left", "fix": ["x", "y"], "displacement": ["0", "0"]}]
    fi.Case.from_dict(_plate(still, method="modal", modes=3, static_correction=False))


def test_a_node_held_still_by_one_support_and_moved_by_another_is_refused():
    """The corner of 'left' (driven in x) and 'bottom' (held still) cannot do both: refused, where
    the motion used to win silently; a motion of the constant 0 agrees with the still support."""
    driven = {"nodes": "left", "fix": ["x"], "displacement": ["0.5*t"]}
    case = fi.Case.from_dict(_plate([{"nodes": "bottom", "fix": ["x", "y"]}, driven]))
    with pytest.raises(CaseError, match=r"supports\[1\].displacement: moves the x component of 1 node\(s\) that "
                                        r"supports\[0\] \(group 'bottom'"):
        fi.run(case)
    agreeing = {"nodes": "left", "fix": ["x", "y"], "displacement": ["0", "0.5*t"]}
    fi.run(fi.Case.from_dict(_plate([{"nodes": "bottom", "fix": ["x"]}, agreeing])))
    # the symmetry axis of an axisymmetric model holds its radial displacement still
    axi = _plate([{"nodes": "left", "fix": ["x"], "displacement": ["0.01*t"]}])
    axi["mesh"]["hypothesis"] = "axisymmetric"
    with pytest.raises(CaseError, match=r"supports\[0\].displacement: moves the x component of .* the symmetry axis"):
        fi.run(fi.Case.from_dict(axi))


def test_the_reduction_study_of_a_moving_support_leaves_out_the_plain_truncation_with_a_warning(tmp_path, caplog):
    """The study runs each n1 with and without static correction; without is refused for a moving support,
    so the study goes on with the rest (it stopped with status 2 after the full run) and says why."""
    from fem_impact.app.studies import reduction_table

    data = {"name": "pushed", "mesh": {"shape": "bar", "dim": 1, "length": 1.0, "cells": 20},
            "material": {"E": 1.0, "rho": 1.0, "nu": 0.0, "area": 1.0},
            "supports": [{"nodes": "left", "fix": ["x"], "displacement": ["0.01*t"]}],
            "contacts": [{"name": "wall", "type": "obstacle", "nodes": "right", "normal": [1.0], "gap": 0.0}],
            "solver": {"dt": 0.025, "t_end": 0.5}, "output": {"vtk": False, "probes": {"middle": [0.5]}}}
    with caplog.at_level("WARNING"):
        rows = reduction_table(fi.Case.from_dict(data), modes=(4,), outdir=tmp_path / "reduction")
    assert [(r["model"], r["modes"], r["static_correction"]) for r in rows] == [("full", None, None),
                                                                                ("modal", 4, True)]
    assert "modal-4-plain: not run: supports[0] moves" in caplog.text


def test_a_contact_on_a_component_its_support_holds_at_the_constant_0_is_taken():
    """The table's base moves in y and holds x at "0": a stop on the right side along x (its corner on the
    base, mean coupling) is taken, as with a support without motion, and is open at rest; along y it is
    refused (its gap would move with the base)."""
    data = {"name": "table", "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.2, "cells": 10},
            "material": {"E": 1.0, "rho": 1.0, "nu": 0.3, "area": 1.0}, "damping": {"alpha": 4.0},
            "supports": [{"nodes": "bottom", "fix": ["x", "y"], "displacement": ["0", "1e-3"]}],
            "contacts": [{"name": "stop", "type": "obstacle", "nodes": "right", "normal": [1.0, 0.0], "gap": 1e-4,
                          "coupling": "mean"}],
            "solver": {"dt": 0.02, "t_end": 12.0}, "output": {"vtk": False, "probes": {"top": [0.5, 0.2]}}}
    h = fi.run(fi.Case.from_dict(data)).history
    assert h["top.uy"][-1] == pytest.approx(1e-3, rel=1e-6) and h["stop.gap"][-1] == pytest.approx(1e-4, rel=1e-6)
    data["contacts"][0]["normal"] = [0.0, 1.0]
    with pytest.raises(CaseError, match=r"contacts\[0\].nodes: acts on nodes whose motion a support prescribes"):
        fi.run(fi.Case.from_dict(data))


def test_a_damped_block_shaken_at_its_base_loses_energy_in_every_step():
    """Rayleigh damping on a block whose base moves on an ellipse (cases/vibromotor_surface.yaml's
    driver, no contact): the whole structure's damping loss is dt V_mean^T C V_mean in every step, so the
    booked loss never decreases and no energy is created (the trapezoidal rule on the support's cross
    terms alone booked a gain of 3e-4 J in 0.002 s); the balance closes within its round-off."""
    case = fi.load_case(CASES / "vibromotor_surface.yaml").with_changes(
        {"contacts": [], "solver.t_end": 0.002, "output.vtk": False, "output.every": 1})
    result = fi.run(case)
    h, summary = result.history, result.summary
    assert np.all(np.diff(h["damping_loss"]) >= 0.0) and h["damping_loss"][-1] > 0.0
    assert summary["energy_created"] == 0.0
    assert np.abs(h["energy_error"]).max() <= max(summary["energy_roundoff"], 1e-12)
