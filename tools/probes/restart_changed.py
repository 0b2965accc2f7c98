"""Class ``restart-changed``: a checkpoint continued under a changed case. A change of what the saved state
depends on (the model, its constraints, the method and its keys, the initial state) is refused in one line
naming the key; a change of the run's time inputs (its loads and the parameters they use, the end, the
output) is applied, and the continued run is then the uninterrupted run that switched to them at the
checkpoint's time (its loads switched between the checkpoint's step and the next), to round-off."""

from __future__ import annotations

import csv
import math

from . import CASES, Verdict, ok, probe, wrong

BAR = CASES / "impacting_bar.yaml"
BLOCK = CASES / "sliding_block.yaml"
BEAM = CASES / "base_excited_beam.yaml"
STOP = CASES / "beam_stop.yaml"
TC = 0.05   # the checkpoints' time
QUIET = ("-q", "--set", "output.vtk=false")

# name: (case, --set options, dt): short runs to TC whose checkpoints the probes continue
CHECKPOINTS = {
    "bar-moreau-jean": (BAR, ["mesh.cells=50", "solver.method=moreau_jean", "solver.dt=0.01"], 0.01),
    "bar-newmark": (BAR, ["mesh.cells=50", "solver.dt=0.01"], 0.01),
    "bar-central-difference": (BAR, ["mesh.cells=50", "solver.method=central_difference", "solver.dt=0.01"], 0.01),
    "bar-modal": (BAR, ["mesh.cells=50", "solver.method=modal", "solver.modes=10", "solver.dt=0.01"], 0.01),
    "bar-modal-modes-only": (BAR, ["mesh.cells=50", "solver.method=modal", "solver.modes=10",
                                   "solver.static_correction=false", "solver.dt=0.01"], 0.01),
    "block-friction": (BLOCK, [], 0.002),
    "beam-shaken": (BEAM, ["mesh.cells=10", "solver.dt=0.01"], 0.01),
    "beam-stop": (STOP, ["mesh.cells=10", "solver.dt=0.001", "solver.method=moreau_jean"], 0.001),
}


def _sets(options) -> list[str]:
    return [arg for option in options for arg in ("--set", option)]


def _checkpoint(ctx, name):
    case, options, _ = CHECKPOINTS[name]

    def build(folder):
        r = ctx.run("run", case, "-o", folder / "run", *QUIET, *_sets(options), "--set", f"solver.t_end={TC}")
        if r.status != 0:
            raise RuntimeError(f"the checkpoint run failed: {r.tail()}")
    return ctx.shared(f"checkpoint-{name}", build) / "run"


def switch(dt: float) -> str:
    """0 up to the checkpoint's time, 1 from its next step on (exactly: the ramp's min and max)."""
    return f"max(0, min(1, (t - {TC + 0.5 * dt!r})/{0.25 * dt!r}))"


# -- refused: (checkpoint, --set option, the key the message must name) ---------------------------------
REFUSED = [
    ("bar-moreau-jean", "solver.level=velocity", "solver.level"),
    ("bar-moreau-jean", "solver.theta=1", "solver.theta"),
    ("bar-moreau-jean", "solver.method=newmark", "solver.method"),
    ("bar-moreau-jean", "solver.dt=0.005", "solver.dt"),
    ("bar-moreau-jean", "solver.mass=lumped", "solver.mass"),
    ("bar-moreau-jean", "solver.mass=redistributed", "solver.mass"),
    ("bar-moreau-jean", "material.E=2", "material.E"),
    ("bar-moreau-jean", "material.rho=2", "material.rho"),
    ("bar-moreau-jean", "material.area=2", "material.area"),
    ("bar-moreau-jean", "mesh.length=2", "mesh.length"),
    ("bar-moreau-jean", "mesh.cells=60", "mesh.cells"),
    ("bar-moreau-jean", "mesh.dim=2", "mesh.dim"),
    ("bar-moreau-jean", "damping.alpha=1", "damping.alpha"),
    ("bar-moreau-jean", "damping.beta=0.01", "damping.beta"),
    ("bar-moreau-jean", "contacts.0.gap=0.2", "contacts.0.gap"),
    ("bar-moreau-jean", "contacts.0.restitution=0.5", "contacts.0.restitution"),
    ("bar-moreau-jean", "contacts.0.stiffness=1000", "contacts.0.stiffness"),
    ("bar-moreau-jean", "contacts.0.nodes=right", "contacts.0.nodes"),
    ("bar-moreau-jean", "contacts=[]", "contacts.0"),
    ("bar-moreau-jean", "supports=[{nodes: right, fix: [x]}]", "supports.0.nodes"),
    ("bar-moreau-jean", "initial.velocity=[-2.0]", "initial.velocity.0"),
    ("bar-newmark", "solver.beta=0.3", "solver.beta"),
    ("bar-newmark", "solver.gamma=0.6", "solver.gamma"),
    ("bar-newmark", "solver.impact_correction=false", "solver.impact_correction"),
    ("bar-central-difference", "solver.mass=consistent", "solver.mass"),
    ("bar-modal", "solver.static_correction=false", "solver.static_correction"),
    ("bar-modal", "solver.scheme=newmark", "solver.scheme"),
    ("bar-modal", "solver.modes=12", "modes"),
    # the static correction holds the saved loads' quasi-static response: a changed load is refused there
    ("bar-modal", "loads=[{nodes: right, force: [-1.0]}]", "loads.0"),
    ("block-friction", "contacts.0.friction=0", "contacts.0.friction"),
    ("block-friction", "contacts.0.friction=0.5", "contacts.0.friction"),
    ("block-friction", "mesh.elements=hex", "mesh.elements"),
    ("block-friction", "parameters.v0=3", "parameters.v0"),   # (the initial velocity's, not a load's)
    ("beam-shaken", 'supports.0.displacement=["0", "2*A*sin(2*pi*f*t)"]', "supports.0.displacement.1"),
    ("beam-stop", "contacts.0.stiffness=2e8", "contacts.0.stiffness"),
    ("beam-stop", "contacts.0.coupling=each", "contacts.0.coupling"),
]


def _refused(name, option, needle):
    def body(ctx):
        saved = _checkpoint(ctx, name)
        case, options, _ = CHECKPOINTS[name]
        out = ctx.folder / "out"
        r = ctx.run("run", case, "-o", out, *QUIET, *_sets(options), "--set", "solver.t_end=0.2", "--set", option,
                    "--restart", saved)
        verdict = ctx.refused(r, needle, "--restart")
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    return body


for _name, _option, _needle in REFUSED:
    probe("restart-changed", f"{_name} --set {_option}: refused")(_refused(_name, _option, _needle))


# -- applied: (checkpoint, --set options of the restart, --set options of the uninterrupted reference) ----
def _applied_cases():
    dt = {name: spec[2] for name, spec in CHECKPOINTS.items()}
    force = lambda f: [f"loads=[{{nodes: right, force: [{f}]}}]"]   # noqa: E731
    yield "bar-moreau-jean", "an added force", force("-1.0"), force(f'"-1.0*{switch(dt["bar-moreau-jean"])}"')
    yield ("bar-moreau-jean", "an added force varying in time", force('"-sin(20*t)"'),
           force(f'"-sin(20*t)*{switch(dt["bar-moreau-jean"])}"'))
    yield "bar-newmark", "an added force", force("-1.0"), force(f'"-1.0*{switch(dt["bar-newmark"])}"')
    yield ("bar-central-difference", "an added force", force("-1.0"),
           force(f'"-1.0*{switch(dt["bar-central-difference"])}"'))
    yield ("bar-modal-modes-only", "an added force", force("-1.0"),
           force(f'"-1.0*{switch(dt["bar-modal-modes-only"])}"'))
    h = switch(dt["block-friction"])
    yield ("block-friction", "parameters.g=20", ["parameters.g=20"],
           [f'loads.0.acceleration=[0.0, "-(g*(1 - {h}) + 20*{h})"]'])
    yield ("block-friction", "a pull along the floor", ['loads.0.acceleration=[2.0, "-g"]'],
           [f'loads.0.acceleration=["2.0*{h}", "-g"]'])
    h = switch(dt["beam-shaken"])
    yield ("beam-shaken", "gravity, on its held nodes too", ["loads=[{body: all, acceleration: [0.0, -9.81]}]"],
           [f'loads=[{{body: all, acceleration: [0.0, "-9.81*{h}"]}}]'])
    h = switch(dt["beam-stop"])
    yield ("beam-stop", "the end force doubled", ["loads.0.force=[0.0, -2000.0]"],
           [f'loads.0.force=[0.0, "-1000.0*(1 - {h}) - 2000.0*{h}"]'])
    yield "bar-moreau-jean", "solver.t_end alone", [], []
    yield "bar-newmark", "output.every=3", ["output.every=3"], ["output.every=3"]
    yield ("bar-moreau-jean", "a probe added", ["output.probes={left: [0.0], right: [1.0], middle: [0.5]}"],
           ["output.probes={left: [0.0], right: [1.0], middle: [0.5]}"])
    yield "block-friction", "output.checkpoint_every=7", ["output.checkpoint_every=7"], []


def _applied(name, changes, reference):
    def body(ctx):
        saved = _checkpoint(ctx, name)
        case, options, _ = CHECKPOINTS[name]
        common = [*QUIET, *_sets(options), "--set", "solver.t_end=0.2"]
        r = ctx.run("run", case, "-o", ctx.folder / "continued", *common, *_sets(changes), "--restart", saved)
        bad = ctx.succeeded(r)
        if bad:
            return bad
        r = ctx.run("run", case, "-o", ctx.folder / "reference", *common, *_sets(reference))
        if r.status != 0:
            return Verdict("error", f"the reference run failed: {r.tail()}")
        differ = _history_differs(ctx.folder / "reference", ctx.folder / "continued")
        return wrong(differ) if differ else ok()
    return body


for _name, _what, _changes, _reference in _applied_cases():
    probe("restart-changed", f"{_name}, {_what}: applied, as the uninterrupted run")(
        _applied(_name, _changes, _reference))


# -- comparing histories -------------------------------------------------------------------------------
ENERGY = ("kinetic", "strain", "external_work", "damping_loss", "impact_loss", "contact_loss", "energy_error",
          "friction_loss", "scheme_energy")


def _read(folder) -> dict[str, list[float]]:
    with open(folder / "history.csv", newline="") as f:
        rows = list(csv.reader(f))
    names = rows[0]
    return {name: [float(row[i]) for row in rows[1:]] for i, name in enumerate(names)}


def _history_differs(reference, continued, tol: float = 1e-10) -> str | None:
    """Where the continued history parts from the reference's, from its first time on (None: nowhere):
    each column to ``tol`` of its scale (an energy term on the energy's), or one unit of history.csv's 12th
    significant digit."""
    full, part = _read(reference), _read(continued)
    if set(full) != set(part):
        return f"columns differ: {sorted(set(full) ^ set(part))}"
    t0 = part["t"][0]
    start = min(range(len(full["t"])), key=lambda i: abs(full["t"][i] - t0))
    if abs(full["t"][start] - t0) > 1e-9 or len(full["t"]) - start != len(part["t"]):
        return f"the continued history has {len(part['t'])} rows from t = {t0}, the reference {len(full['t']) - start}"
    energy = max(k + s for k, s in zip(full["kinetic"], full["strain"]))
    for name, column in full.items():
        scale = max(max(abs(v) for v in column), energy if name in ENERGY else 1e-300)
        for a, b, t in zip(column[start:], part[name], part["t"]):
            digit = 10.0 ** (math.floor(math.log10(max(abs(a), abs(b), 1e-300))) - 11)
            if abs(a - b) > max(tol * scale, 1.0001 * digit):
                return f"{name} at t = {t:.6g}: {b!r}, the uninterrupted run {a!r}"
    return None
