"""Class ``surface-contacts``: contacts between surfaces meshed apart (``type: surface``: rows found by a
search on the geometry at t = 0, mortar rows with dual multipliers in 2D, node-to-segment rows where a node's
segments are only partly covered and in 3D; a run whose rows slid past a quarter of a cell stops, "small
sliding", unless Moreau-Jean on the full model finds them again): cases/contact_patch.yaml as it is and
changed (the roles swapped, triangles, restitution, gravity, a moving support, friction, a narrower upper
block); the upper block dropped at 1 m/s on the lower one with every method, friction, damping, a gap, the
output's options, checkpoints, restarts, 2 MPI ranks and SIGINT;
the sliding watch; the 3D boxes; a rigid upper block; Hertz's cylinder; and what a surface contact refuses.

Each probe judges an exact answer where there is one, or a refusal in one line naming the key:

- the contact patch test (meshes/two_blocks.py: 5 cells against 7, plane stress 10 mm thick, p on the lid):
  u = (nu p x / E, -p y / E) in each block, the upper one carried down by the lower's shortening, every node
  to 1e-8 of the largest displacement; the contact force p * 0.1 * 0.01 to 1e-10 (in 3D, on node-to-segment
  rows: the force p * 0.1 * 0.1 to 1e-10, the field within 5 %: tests/test_surface.py measured 3.5 %);
- the upper block dropped at v0 = 1 m/s (no loads): no energy created (summary ``energy_created`` 0, E <= E0 +
  W_ext), the balance closed, the upper block's momentum changed by the contact's impulses (and by its
  friction impulses along the face), its penetration within a hundredth of a step's travel (within the
  documented drift (1 - theta) dt v0 where Newton's law is on velocities: friction, rigid bodies);
- the upper block sent along the lower one at 1 m/s: a method that keeps the rows of t = 0 stops once a row
  slid a quarter of its cell (0.1 / 7 / 4 m, about 3.6 ms), in one line naming the contact and "small
  sliding", status not 0, no traceback, the output folder as it was; Moreau-Jean, where it finds the rows
  again, keeps the block's speed exactly (no force on a free slide) and continues exactly from a checkpoint;
- Hertz's cylinder (plane strain, a = R / 10): the half-width within a cell, the peak pressure within 5 %;
- a key a surface contact does not take is refused (status 2, one line naming it, nothing written).
"""

from __future__ import annotations

import json
import re
import signal
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import yaml

from . import CASES, ROOT, Verdict, history, ok, probe, restart_parts, run_case, solved, wrong

PATCH = CASES / "contact_patch.yaml"
MESH = ROOT / "meshes" / "two_blocks.msh"
P, WIDTH, H, THICK = 1e6, 0.1, 0.05, 0.01              # the case's pressure, the blocks' size, the thickness
LOWER, UPPER = (210e9, 0.3), (70e9, 0.33)               # (E, nu): steel under aluminium
FORCE = P * WIDTH * THICK                               # the contact's force in the patch test
M_UPPER, M_LOWER = 2700.0 * WIDTH * H * THICK, 7800.0 * WIDTH * H * THICK
V0, DT = 1.0, 1e-6                                      # the dropped block's speed, the drop's step
CELL = WIDTH / 7                                        # the upper face's cells: a row slides CELL / 4 at most
G = 9.81
NAME = "face"


# -- the scenes -------------------------------------------------------------------------------------------
def _patch(vtk: bool = True, **top) -> dict:
    """cases/contact_patch.yaml as a dict (its mesh by its absolute path), VTK at its first and last step;
    ``top``: keys replaced."""
    data = yaml.safe_load(PATCH.read_text())
    data["mesh"] = {"file": str(MESH)}
    data["output"] = {"vtk": vtk, "every": 5}
    data.update(top)
    return data


def _contact(**extra) -> dict:
    return {"name": NAME, "type": "surface", "nodes": "upper_bottom", "surface": "lower_top", **extra}


def _drop(method: str = "moreau_jean", dt: float = DT, t_end: float = 1e-4, velocity=(0.0, -V0),
          solver: dict | None = None, **top) -> dict:
    """The patch's blocks, no loads, the lower one held on its base, the upper one launched at ``velocity``;
    ``solver``: more solver keys; ``top``: keys replaced."""
    data = _patch(vtk=False)
    data["output"] = {"vtk": False, "every": 1}
    data["loads"] = []
    data["supports"] = [{"nodes": "base", "fix": "all"}]
    data["initial"] = {"velocity": [{"body": "upper", "value": list(velocity)}]}
    data["solver"] = {"method": method, "dt": dt, "t_end": t_end, **(solver or {})}
    data.update(top)
    return data


def _slide(method: str = "newmark", t_end: float = 0.01) -> dict:
    """The upper block sent along the lower one at 1 m/s, no loads (tests/test_surface.py's)."""
    return _drop(method, dt=1e-5, t_end=t_end, velocity=(V0, 0.0), solver={"modes": 20} if method == "modal" else None)


def _boxes(ctx, **top) -> dict:
    """The patch test on meshes/two_blocks.py's boxes (hexahedra, 5 cells against 7, 3 up), held by symmetry
    on x = 0 and z = 0."""
    data = _patch(mesh={"file": str(_mesh(ctx, "boxes", "--3d"))})
    for material in data["materials"].values():
        material.pop("area")
    data["supports"] = [{"nodes": "base", "fix": ["y"]}, {"nodes": "left", "fix": ["x"]},
                        {"nodes": "back", "fix": ["z"]}]
    data["loads"] = [{"nodes": "lid", "traction": [0.0, "-p", 0.0]}]
    data.update(top)
    return data


def _summary(ctx, out: str = "out") -> dict:
    return json.loads((ctx.folder / out / "summary.json").read_text())


# -- meshes of the probes' own (built once, in a process of their own) --------------------------------------
_SCRIPT = '''"""Two blocks (meshes/two_blocks.py): ``span`` a narrower upper one; ``corner`` node groups of one node."""
import sys
from importlib.util import module_from_spec, spec_from_file_location

import gmsh

spec = spec_from_file_location("two_blocks", sys.argv[1])
blocks = module_from_spec(spec)
spec.loader.exec_module(blocks)
kind, out = sys.argv[2], sys.argv[3]
if kind == "span":
    blocks.build(out, 10, 5, span=(0.025, 0.075))
    sys.exit(0)
blocks.build(out)
gmsh.initialize(["", "-v", "0"])
try:
    gmsh.open(out)
    bodies = {gmsh.model.getPhysicalName(2, tag): tag for _, tag in gmsh.model.getPhysicalGroups(2)}
    for body, name in (("lower", "lower_corner"), ("upper", "upper_corner")):
        surfaces = gmsh.model.getEntitiesForPhysicalGroup(2, bodies[body])
        points = [t for d, t in gmsh.model.getBoundary([(2, s) for s in surfaces], recursive=True) if d == 0]
        at = [t for t in points
              if max(abs(a - b) for a, b in zip(gmsh.model.getValue(0, t, []), (0.1, 0.05, 0.0))) < 1e-9]
        for t in at:   # (a point read back from a .msh has its node, not its element)
            gmsh.model.mesh.addElementsByType(t, 15, [], gmsh.model.mesh.getNodes(0, t)[0])
        gmsh.model.setPhysicalName(0, gmsh.model.addPhysicalGroup(0, at), name)
    gmsh.write(out)
finally:
    gmsh.finalize()
'''


def _mesh(ctx, key: str, *args: str) -> Path:
    """A mesh of meshes/two_blocks.py (its options ``args``; ``span`` or ``corner``: _SCRIPT's), or of
    meshes/hertz_cylinder.py (``hertz``), built once for every probe."""
    def build(folder):
        out = folder / "mesh.msh"
        if key in ("span", "corner"):
            script = folder / "blocks.py"
            script.write_text(_SCRIPT)
            r = ctx.run(script, ROOT / "meshes" / "two_blocks.py", key, out, python=True)
        else:
            source = "hertz_cylinder.py" if key == "hertz" else "two_blocks.py"
            r = ctx.run(ROOT / "meshes" / source, *args, "-o", out, python=True)
        if r.status != 0 or not out.is_file():
            raise RuntimeError(f"the mesh {key} could not be made: {r.tail()}")
    return ctx.shared(f"surface-mesh-{key}", build) / "mesh.msh"


# -- reading the fields ------------------------------------------------------------------------------------
def _frames(folder: Path) -> list[tuple[float, str]]:
    return [(float(d.get("timestep")), d.get("file")) for d in ET.parse(folder / "results.pvd").iter("DataSet")]


def _last_frame(folder: Path, upper_above: float = H) -> dict:
    """The last VTK frame's owned points: coordinates ``x``, ``u``, ``contact_force``, and ``upper``
    (whether a cell whose centre is above ``upper_above`` in y holds the point), over every piece."""
    frame = ET.parse(folder / _frames(folder)[-1][1]).getroot()
    parts: dict[str, list] = {"x": [], "u": [], "contact_force": [], "upper": []}
    for piece in frame.iter("Piece"):
        root = ET.parse(folder / piece.get("Source")).getroot()
        grid = root.find("UnstructuredGrid/Piece")
        x = np.array(grid.find("Points/DataArray").text.split(), dtype=float).reshape(-1, 3)
        cells = {d.get("Name"): np.array(d.text.split(), dtype=np.int64) for d in grid.find("Cells")}
        point = {d.get("Name"): np.array(d.text.split(), dtype=float) for d in grid.find("PointData")}
        starts = np.concatenate([[0], cells["offsets"][:-1]])
        upper = np.zeros(len(x), dtype=bool)
        for a, b in zip(starts, cells["offsets"], strict=True):
            nodes = cells["connectivity"][a:b]
            if x[nodes, 1].mean() > upper_above:
                upper[nodes] = True
        owned = point.get("vtkGhostType", np.zeros(len(x))) == 0
        parts["x"].append(x[owned])
        parts["upper"].append(upper[owned])
        for name in ("u", "contact_force"):
            parts[name].append(point[name].reshape(-1, 3)[owned])
    return {k: np.concatenate(v) for k, v in parts.items()}


def _exact(x: np.ndarray, upper: np.ndarray, dim: int = 2, p: float = P, lower=LOWER, top=UPPER) -> np.ndarray:
    """The patch test's field (plane stress in 2D; in 3D the same across z): each block under sigma_yy = -p."""
    E = np.where(upper, top[0], lower[0])
    nu = np.where(upper, top[1], lower[1])
    uy = np.where(upper, -p * H / lower[0] - p * (x[:, 1] - H) / E, -p * x[:, 1] / E)
    u = np.column_stack([nu * p * x[:, 0] / E, uy, nu * p * x[:, 2] / E if dim == 3 else np.zeros(len(x))])
    return u


def _field_error(folder: Path, dim: int = 2, shift=(0.0, 0.0, 0.0), **exact) -> float:
    """The largest nodal error of the last frame against the patch test's field (moved by ``shift``), over the
    largest displacement."""
    f = _last_frame(folder)
    want = _exact(f["x"], f["upper"], dim, **exact) + np.asarray(shift)
    return float(np.abs(f["u"] - want).max() / np.abs(want).max())


def _periods(path: Path) -> dict:
    import csv

    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    values = np.array(rows[1:], dtype=float)
    return {name: values[:, k] for k, name in enumerate(rows[0])}


# -- judging ------------------------------------------------------------------------------------------------
def _budget(h: dict, s: dict, problems: list, closes: float = 1e-9) -> None:
    """No energy created (the summary's and E <= E0 + W_ext from the run's own initial energy: a Newmark
    history's first row is after its impact at t = 0), the balance closed, the losses >= 0 (the contact's
    and the impacts' together: Newmark's position-level forces give work back as a row releases,
    docs/theory.md s. 9), the friction loss never falling; to ``closes`` of the energy scale. E includes
    central difference's ``scheme_energy``."""
    E = h["kinetic"] + h["strain"] + h.get("scheme_energy", 0.0)
    E0 = s["initial_energy"]
    scale = max(E0, E.max(), np.abs(h["external_work"]).max(), 1e-300)
    if s.get("energy_created", 0.0) != 0.0:
        problems.append(f"summary energy_created {s['energy_created']:.3g} at t = {s.get('energy_created_at')}")
    if np.max(E - E0 - h["external_work"]) > closes * scale + s.get("energy_roundoff", 0.0):
        problems.append(f"E > E0 + W_ext by {np.max(E - E0 - h['external_work']):.3g} of {scale:.3g}")
    if np.abs(h["energy_error"]).max() > closes * scale:
        problems.append(f"balance residual {np.abs(h['energy_error']).max():.3g} of {scale:.3g}")
    contact = h["impact_loss"] + h["contact_loss"]
    if contact.min() < -closes * scale:
        problems.append(f"impact_loss + contact_loss down to {contact.min():.3g}")
    for loss in ("damping_loss", "friction_loss"):
        if loss in h and h[loss].min() < -closes * scale:
            problems.append(f"{loss} down to {h[loss].min():.3g}")
    if "friction_loss" in h and np.diff(h["friction_loss"]).min() < -closes * scale:
        problems.append(f"friction_loss falls by {np.diff(h['friction_loss']).min():.3g} in a step")


def _dropped(h: dict, s: dict, problems: list, mass: float = M_UPPER, v0=(0.0, -V0), drift: float = 0.0,
             dt: float = DT, axes: str = "xy", g: float = 0.0) -> None:
    """The dropped block: its momentum from its initial m v0 changed by the impulses (normal along y, friction
    along x; less m g t under gravity), its penetration within a hundredth of a step's travel (+ ``drift``)."""
    impulse = h[f"{NAME}.impulse"].sum()
    gained = h["upper.py"][-1] - mass * v0[1]
    want = impulse - mass * g * h["t"][-1]
    if abs(gained - want) > 1e-9 * mass * V0:
        problems.append(f"the upper block's y momentum changed by {gained:.12g}, the impulses {want:.12g}")
    if impulse <= 0.0:
        problems.append("no impulse: the block was never stopped")
    if f"{NAME}.tx" in h:
        along = h["upper.px"][-1] - mass * v0[0]
        friction = h[f"{NAME}.tx"].sum() * dt
        if abs(along - friction) > 1e-9 * mass * V0:
            problems.append(f"the upper block's x momentum changed by {along:.12g}, its friction impulses "
                            f"{friction:.12g}")
    allowed = 0.01 * V0 * dt + drift
    if s["max_penetration"] > allowed:
        problems.append(f"max_penetration {s['max_penetration']:.3g} m, above {allowed:.3g} m")


def _stopped(ctx, r, out: Path, when: float | None = CELL / 4 / V0, tolerance: float = 0.05,
             kept: bool = False, mpi: bool = False) -> Verdict:
    """The sliding watch's stop: status not 0, no traceback, one line naming the contact and 'small sliding'
    (the time within ``tolerance`` of ``when``; under ``mpi`` mpirun's own report of the status beside it),
    the output folder as it was (absent, or the kept result), and nothing of the run's left beside it."""
    if r.traceback:
        return Verdict("traceback", r.tail())
    if r.status == 0:
        return wrong(f"the run went on (status 0) though its rows slid past a quarter cell: {r.tail()}")
    mine = [line for line in r.lines() if line.startswith("fem-impact:")]
    if len(mine) != 1 or (len(r.lines()) != 1 and not mpi):
        return wrong(f"{len(r.lines())} lines on stderr, {len(mine)} of fem-impact's (status {r.status}): {r.tail(4)}")
    line = mine[0]
    if f"contact {NAME}" not in line or "small sliding" not in line:
        return wrong(f"the line does not name 'contact {NAME}' and 'small sliding': {line}")
    found = re.search(r"by t = ([-+0-9.eE]+) s", line)
    if when is not None and (found is None or abs(float(found.group(1)) - when) > tolerance * when):
        return wrong(f"stopped at {found.group(1) if found else '?'} s, a quarter cell at 1 m/s is {when:.4g} s: "
                     f"{line}")
    if not kept and out.exists():
        return wrong(f"stopped, yet {out} was written")
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]:
        time.sleep(0.1)
    left = [p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]
    if left:
        return wrong(f"left beside the output folder: {left}")
    return ok(line[:120])


def _scale(h: dict, name: str) -> float:
    """A column's physical scale (round-off in a column of zeros is not a difference)."""
    energy = max((h["kinetic"] + h["strain"]).max(), 1e-300)
    if name in ("energy_error", "external_work", "kinetic", "strain", "numerical_loss") or name.endswith("_loss"):
        return energy
    body, _, column = name.partition(".")
    if column in ("px", "py", "pz"):
        return max(M_UPPER * V0, *(np.abs(h[f"{body}.p{c}"]).max() for c in "xyz" if f"{body}.p{c}" in h))
    if column == "gap":   # (round-off on coordinates of 0.1 m)
        return max(np.abs(h[name]).max(), 1e-4)
    if column in ("tx", "ty", "tz", "tangential_force"):
        return max(np.abs(h[f"{body}.force"]).max(), 1e-300)
    return max(np.abs(h[name]).max(), 1e-300)


def _differ(a: dict, b: dict, tol: float = 1e-10) -> str | None:
    """Where ``b`` (a run's last rows) parts from ``a``'s, column by column on its scale (None: nowhere)."""
    if set(a) != set(b):
        return f"columns differ: {sorted(set(a) ^ set(b))}"
    n = b["t"].size
    worst = max((np.abs(a[k][-n:] - b[k]).max() / _scale(a, k), k) for k in a)
    return None if worst[0] <= tol else f"{worst[1]} parts by {worst[0]:.3g} of its scale"


def _refusal(ctx, data: dict, *needles: str, status: int = 2) -> Verdict:
    r, out = run_case(ctx, data)
    verdict = ctx.refused(r, *needles, status=status, max_lines=1)
    if verdict.kind == "ok" and out.exists():
        return wrong(f"refused, yet {out} was written")
    return verdict


# -- the contact patch test ---------------------------------------------------------------------------------
def _patch_exact(data: dict, shift=(0.0, 0.0, 0.0), force: float = FORCE, **exact):
    """A probe: ``data`` run; every node's displacement the patch test's (+ ``shift``) to 1e-8, the contact
    force ``force`` to 1e-10, no energy created."""
    def body(ctx):
        h, bad = solved(ctx, data)
        if bad:
            return bad
        problems: list = []
        error = _field_error(ctx.folder / "out", shift=shift, **exact)
        if error > 1e-8:
            problems.append(f"the field off the exact linear one by {error:.3g} of the largest displacement")
        if abs(h[f"{NAME}.force"][-1] - force) > 1e-10 * force:
            problems.append(f"contact force {h[f'{NAME}.force'][-1]:.12g}, exact {force:.12g}")
        s = _summary(ctx)
        if s["energy_created"] != 0.0:
            problems.append(f"energy_created {s['energy_created']:.3g}")
        if s["max_penetration"] > 1e-13:   # (round-off on coordinates of 0.1 m)
            problems.append(f"max_penetration {s['max_penetration']:.3g} m")
        return wrong("; ".join(problems)) if problems else ok(f"field to {error:.2g}")
    return body


@probe("surface-contacts", "contact_patch.yaml as it is: every node's u the exact linear field to 1e-8, the force "
                           "p * 0.1 * 0.01 to 1e-10, each face's nodes carry it, 8 rows")
def _as_is(ctx):
    data = _patch()
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    out = ctx.folder / "out"
    error = _field_error(out)
    if error > 1e-8:
        problems.append(f"the field off the exact linear one by {error:.3g} of the largest displacement")
    if abs(h[f"{NAME}.force"][-1] - FORCE) > 1e-10 * FORCE:
        problems.append(f"contact force {h[f'{NAME}.force'][-1]:.12g}, exact {FORCE}")
    f = _last_frame(out)
    face = np.abs(f["x"][:, 1] - H) < 1e-9
    for side, sign in ((f["upper"], 1.0), (~f["upper"], -1.0)):
        carried = f["contact_force"][face & side, 1].sum()
        if abs(carried - sign * FORCE) > 1e-9 * FORCE:
            problems.append(f"the {'upper' if sign > 0 else 'lower'} face's nodes carry {carried:.12g} in y, "
                            f"exact {sign * FORCE}")
    s = _summary(ctx)
    if s["constraints"] != 8 or s["energy_created"] != 0.0 or s["impacts"].get(NAME) != 1 \
            or s["max_penetration"] > 1e-13:
        problems.append(f"summary: constraints {s['constraints']} (8 nodes), energy_created {s['energy_created']}, "
                        f"impacts {s['impacts']}, max_penetration {s['max_penetration']:.3g}")
    return wrong("; ".join(problems)) if problems else ok(f"field to {error:.2g}")


probe("surface-contacts", "the patch test with the roles swapped (nodes: lower_top, surface: upper_bottom): exact")(
    _patch_exact(_patch(contacts=[_contact(nodes="lower_top", surface="upper_bottom")])))
probe("surface-contacts", "the patch test with Newton's restitution e = 0.5: the static answer unchanged, exact")(
    _patch_exact(_patch(contacts=[_contact(restitution=0.5)])))
probe("surface-contacts", "the patch test with its base moving down (a moving support): the exact field carried "
                          "along by the base's motion")(
    _patch_exact(_patch(supports=[{"nodes": "base", "fix": ["y"], "displacement": ["-1e-6*t/0.05"]},
                                  {"nodes": "left", "fix": ["x"]}]), shift=(0.0, -1e-6, 0.0)))


@probe("surface-contacts", "the patch test on triangles (5 cells against 8): exact")
def _triangles(ctx):
    data = _patch(mesh={"file": str(_mesh(ctx, "triangles", "--cells", "5", "--upper", "8", "--triangles"))})
    return _patch_exact(data)(ctx)


@probe("surface-contacts", "the patch test under gravity on both blocks: the force p * 0.1 * 0.01 + m_upper g")
def _gravity(ctx):
    data = _patch(vtk=False)
    data["loads"] = data["loads"] + [{"body": b, "acceleration": [0.0, -G]} for b in ("lower", "upper")]
    h, bad = solved(ctx, data)
    if bad:
        return bad
    want = FORCE + M_UPPER * G
    problems: list = []
    if abs(h[f"{NAME}.force"][-1] - want) > 1e-10 * want:
        problems.append(f"contact force {h[f'{NAME}.force'][-1]:.12g}, exact {want:.12g}")
    _budget(h, _summary(ctx), problems)
    return wrong("; ".join(problems)) if problems else ok()


@probe("surface-contacts", "the patch test with friction 0.3: the normal force exact, Coulomb's cone, no row "
                           "left inside the surface")
def _friction_patch(ctx):
    mu = 0.3
    data = _patch(vtk=False, contacts=[_contact(friction=mu)])
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    if abs(h[f"{NAME}.force"][-1] - FORCE) > 1e-10 * FORCE:
        problems.append(f"contact force {h[f'{NAME}.force'][-1]:.12g}, exact {FORCE}")
    N, T = h[f"{NAME}.force"], h[f"{NAME}.tangential_force"]
    if np.any(T > mu * N * (1 + 1e-9) + 1e-9 * FORCE):
        problems.append(f"outside the cone: T / N up to {np.max(T[N > 0] / N[N > 0]):.6g}")
    scale = P * H / LOWER[0] + P * H / UPPER[0]   # (the lid's displacement)
    inside = np.flatnonzero(h[f"{NAME}.gap"] < -1e-13)   # (round-off on coordinates of 0.1 m)
    if inside.size:
        gap = h[f"{NAME}.gap"].min()
        problems.append(f"a row {-gap:.3g} m inside the surface ({-gap / scale:.2f} times the lid's displacement "
                        f"{scale:.3g} m) from t = {h['t'][inside[0]]:g} to the end (gap {h[f'{NAME}.gap'][-1]:.3g} "
                        f"at t = {h['t'][-1]:g}), at theta = 1 where the velocity level's drift (1 - theta) dt |v_N| "
                        "is 0")
    _budget(h, _summary(ctx), problems)
    return wrong("; ".join(problems)) if problems else ok()


@probe("surface-contacts", "a narrower upper block (its face over 5 of the lower's 10 cells) as the surface: "
                           "mortar, node-to-segment and unpaired rows carry p * 0.05 * 0.01 exactly")
def _narrower(ctx):
    data = _patch(vtk=False, mesh={"file": str(_mesh(ctx, "span"))},
                  contacts=[_contact(nodes="lower_top", surface="upper_bottom")])
    h, bad = solved(ctx, data)
    if bad:
        return bad
    want = P * 0.05 * THICK
    problems: list = []
    if abs(h[f"{NAME}.force"][-1] - want) > 1e-10 * want:
        problems.append(f"contact force {h[f'{NAME}.force'][-1]:.12g}, exact {want:.12g} (the upper block's lid)")
    s = _summary(ctx)
    if s["energy_created"] != 0.0 or s["max_penetration"] > 1e-13:
        problems.append(f"energy_created {s['energy_created']}, max_penetration {s['max_penetration']:.3g}")
    return wrong("; ".join(problems)) if problems else ok()


# -- the upper block dropped ----------------------------------------------------------------------------------
METHODS = {
    "moreau_jean": {},
    "newmark": {},
    "central_difference": {"mass": "lumped", "dt": 2.5e-7},   # (2 / omega_max = 1.2e-6 on the consistent mass)
    "modal": {"modes": 40},
}


def _dropped_with(method: str):
    def body(ctx):
        solver = dict(METHODS[method])
        data = _drop(method, dt=solver.pop("dt", DT), solver=solver)
        h, bad = solved(ctx, data)
        if bad:
            return bad
        s = _summary(ctx)
        problems: list = []
        _dropped(h, s, problems, dt=data["solver"]["dt"])
        _budget(h, s, problems)
        return wrong("; ".join(problems)) if problems else ok(f"impulse {h[f'{NAME}.impulse'].sum():.5f}")
    return body


for _method in METHODS:
    probe("surface-contacts", f"the upper block dropped at 1 m/s, {_method}: momentum by the impulses, no energy "
                              f"created, the balance closed, no penetration")(_dropped_with(_method))


@probe("surface-contacts", "dropped obliquely (0.3, -1) with friction 0.3: both momenta by the impulses, Coulomb's "
                           "cone, the friction loss growing, the drift within (1 - theta) dt v0")
def _dropped_friction(ctx):
    mu = 0.3
    data = _drop(velocity=(0.3, -V0))
    data["contacts"] = [_contact(friction=mu)]
    h, bad = solved(ctx, data)
    if bad:
        return bad
    s = _summary(ctx)
    problems: list = []
    _dropped(h, s, problems, v0=(0.3, -V0), drift=0.5 * DT * V0)
    N, T = h[f"{NAME}.force"], h[f"{NAME}.tangential_force"]
    if np.any(T > mu * N * (1 + 1e-9) + 1e-12 * np.abs(N).max()):
        problems.append(f"outside the cone: T / N up to {np.max(T[N > 0] / N[N > 0]):.9g}")
    if not h["friction_loss"][-1] > 0.0:
        problems.append("no friction loss, though struck obliquely")
    _budget(h, s, problems)
    return wrong("; ".join(problems)) if problems else ok(f"friction loss {h['friction_loss'][-1]:.3g}")


@probe("surface-contacts", "dropped with stiffness damping (beta): the damping loss grows, the balance closes")
def _dropped_damped(ctx):
    data = _drop(damping={"beta": 1e-7})
    h, bad = solved(ctx, data)
    if bad:
        return bad
    s = _summary(ctx)
    problems: list = []
    _dropped(h, s, problems)
    if not h["damping_loss"][-1] > 0.0:
        problems.append("no damping loss")
    _budget(h, s, problems)
    return wrong("; ".join(problems)) if problems else ok(f"damping loss {h['damping_loss'][-1]:.3g}")


@probe("surface-contacts", "lifted 1 mm (initial.displacement), under gravity: free fall until t = gap / v0 "
                           "exactly, then stopped by the impulses")
def _lifted(ctx):
    gap, dt = 1e-3, 1e-5
    data = _drop(dt=dt, t_end=1.2e-3)
    data["initial"]["displacement"] = [{"body": "upper", "value": [0.0, gap]}]
    data["loads"] = [{"body": b, "acceleration": [0.0, -G]} for b in ("lower", "upper")]
    h, bad = solved(ctx, data)
    if bad:
        return bad
    s = _summary(ctx)
    problems: list = []
    t_hit = (-V0 + np.sqrt(V0 ** 2 + 2 * G * gap)) / G   # gap = v0 t + g t^2 / 2
    pushed = np.flatnonzero(h[f"{NAME}.impulse"] > 0.0)
    if not pushed.size or not (t_hit <= h["t"][pushed[0]] < t_hit + dt * (1 + 1e-9)):
        problems.append(f"first impulse at {h['t'][pushed[0]] if pushed.size else None}, the gap closes at {t_hit:.6g}")
    before = h["t"] < t_hit - dt
    fall = -M_UPPER * (V0 + G * h["t"][before])
    if np.abs(h["upper.py"][before] - fall).max() > 1e-9 * M_UPPER * V0:
        problems.append(f"the upper block's fall off m (v0 + g t) by {np.abs(h['upper.py'][before] - fall).max():.3g}")
    _dropped(h, s, problems, dt=dt, g=G)
    _budget(h, s, problems)
    return wrong("; ".join(problems)) if problems else ok(f"first impulse at {h['t'][pushed[0]]:.6g}")


@probe("surface-contacts", "output.period: periods.csv's impulses (a step's in the period [kT, (k+1)T) its end falls "
                           "in, as documented) and impacts those of the history and summary")
def _period(ctx):
    T = 2e-5
    data = _drop()
    data["output"]["period"] = T
    h, bad = solved(ctx, data)
    if bad:
        return bad
    out = ctx.folder / "out"
    p = _periods(out / "periods.csv")
    problems: list = []
    if not np.allclose(p["t"], T * np.arange(1, 6), rtol=1e-9):
        problems.append(f"periods end at {p['t']}")
    total = h[f"{NAME}.impulse"].sum()
    if abs(p[f"{NAME}.impulse"].sum() - total) > 1e-9 * total:
        problems.append(f"the periods' impulse {p[f'{NAME}.impulse'].sum():.12g}, the history's {total:.12g}")
    impacts = _summary(ctx)["impacts"][NAME]
    if p[f"{NAME}.impacts"].sum() != impacts:
        problems.append(f"{p[f'{NAME}.impacts'].sum():g} impacts in the periods, {impacts} in the summary")
    for k, end in enumerate(p["t"]):
        inside = (h["t"] >= (end - T) * (1 - 1e-12)) & (h["t"] < end * (1 - 1e-12)) & (h["t"] > 0)
        if abs(p[f"{NAME}.impulse"][k] - h[f"{NAME}.impulse"][inside].sum()) > 1e-9 * total:
            problems.append(f"period {k + 1}: impulse {p[f'{NAME}.impulse'][k]:.9g}, the history's "
                            f"{h[f'{NAME}.impulse'][inside].sum():.9g}")
    return wrong("; ".join(problems[:3])) if problems else ok()


@probe("surface-contacts", "VTK on: the history as with VTK off, a frame every 2 steps, the last frame's contact "
                           "forces balancing")
def _vtk(ctx):
    off, bad = solved(ctx, _drop(t_end=1e-5), out="off")
    if bad:
        return bad
    data = _drop(t_end=1e-5)
    data["output"] = {"vtk": True, "every": 2}
    on, bad = solved(ctx, data, out="on")
    if bad:
        return bad
    problems: list = []
    differ = _differ(off, on, tol=0.0)
    if differ:
        problems.append(f"VTK changed the history: {differ}")
    times = [t for t, _ in _frames(ctx.folder / "on")]
    if not np.allclose(times, 2 * DT * np.arange(6), rtol=1e-9, atol=1e-15):
        problems.append(f"frames at {times}, expected every 2 steps to 1e-5")
    f = _last_frame(ctx.folder / "on")
    total = np.abs(f["contact_force"][:, :2].sum(axis=0)).max()
    upper = f["contact_force"][f["upper"], 1].sum()
    if total > 1e-9 * abs(upper) or upper <= 0.0:
        problems.append(f"the last frame's contact forces: the upper block's {upper:.6g} in y, all nodes' "
                        f"{f['contact_force'][:, :2].sum(axis=0)}")
    return wrong("; ".join(problems)) if problems else ok(f"{len(times)} frames")


# -- checkpoints, restarts, MPI, signals ---------------------------------------------------------------------
@probe("surface-contacts", "restart (output.checkpoint_every: 10): the oblique frictional drop continues exactly")
def _restart(ctx):
    data = _drop()
    data["contacts"] = [_contact(friction=0.3)]
    data["initial"]["velocity"][0]["value"] = [0.3, -V0]
    data["output"]["checkpoint_every"] = 10
    bad, worst = restart_parts(ctx, data, 4e-5, 1e-4)
    if bad:
        return bad
    return ok() if worst <= 1e-12 else wrong(f"the continued run parts from the whole one by {worst:.3g}")


def _saved(ctx) -> Path:
    """A saved run of the drop to 4e-5 (built once, copied into the probe's folder)."""
    def build(folder):
        r, _ = run_case(ctx, _drop(t_end=4e-5), out=str(folder / "run"))
        if r.status != 0:
            raise RuntimeError(f"the saved run failed: {r.tail()}")
    return ctx.shared("surface-saved", build) / "run"


def _restart_changed(what: str, change, *needles: str):
    def body(ctx):
        saved = _saved(ctx)
        ctx.keep(saved)
        data = _drop()
        change(data["contacts"][0])
        r, out = run_case(ctx, data, "--restart", saved)
        verdict = ctx.refused(r, *needles, "--restart", max_lines=1)
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    probe("surface-contacts", f"restart with {what}: refused in one line naming the key, nothing written")(body)


_restart_changed("friction added", lambda c: c.update(friction=0.2), "contacts.0.friction")


@probe("surface-contacts", "the oblique frictional drop on 2 MPI ranks: the serial history", timeout=300)
def _two_ranks(ctx):
    data = _drop(velocity=(0.3, -V0))
    data["contacts"] = [_contact(friction=0.3)]
    a, bad = solved(ctx, data, out="serial")
    if bad:
        return bad
    b, bad = solved(ctx, data, mpi=2, out="mpi")
    if bad:
        return bad
    differ = _differ(a, b)
    return wrong(f"2 ranks: {differ}") if differ else ok()


@probe("surface-contacts", "the oblique frictional drop's contact_state field (xdmf, every step): 0, 1 or 2 at every "
                           "node, stick and slip both seen, the same on 2 MPI ranks node by node", timeout=300)
def _contact_state(ctx):
    from fem_impact.app.xdmf import open_xdmf

    data = _drop(velocity=(0.3, -V0))
    data["contacts"] = [_contact(friction=0.3)]
    data["output"] = {"vtk": True, "format": "xdmf", "every": 1}
    states = []
    for out, mpi in (("serial", 0), ("mpi", 2)):
        r, folder = run_case(ctx, data, mpi=mpi, out=out)
        bad = ctx.succeeded(r)
        if bad:
            return bad
        with open_xdmf(folder / "results.xdmf") as series:
            x = series.points.T[::-1]
            # (by the nodes' coordinates; two bodies' nodes at one point by their states: their order is the
            # partition's)
            states.append(np.array([d["contact_state"].ravel()[np.lexsort((d["contact_state"].ravel(), *x))]
                                    for _, d in series.frames()]))
    serial, parallel = states
    problems = []
    if np.abs(serial - np.rint(serial)).max() > 1e-12 or not np.isin(np.rint(serial), (0, 1, 2)).all():
        problems.append("a contact_state value other than 0, 1, 2")
    seen = set(np.unique(np.rint(serial)).astype(int))
    if not {1, 2} <= seen:
        problems.append(f"states seen {sorted(seen)}: stick and slip expected in an oblique frictional drop")
    if serial.shape != parallel.shape or np.abs(serial - parallel).max() > 1e-9:
        problems.append("contact_state on 2 ranks differs from the serial run's")
    return wrong("; ".join(problems)) if problems else ok(f"{len(serial)} frames, states {sorted(seen)}")


@probe("surface-contacts", "the patch test on 2 MPI ranks: every node's u exact on both pieces, the serial history",
       timeout=300)
def _two_ranks_patch(ctx):
    a, bad = solved(ctx, _patch(), out="serial")
    if bad:
        return bad
    b, bad = solved(ctx, _patch(), mpi=2, out="mpi")
    if bad:
        return bad
    problems: list = []
    error = _field_error(ctx.folder / "mpi")
    if error > 1e-8:
        problems.append(f"the field on 2 ranks off the exact one by {error:.3g}")
    differ = _differ(a, b, tol=1e-8)   # (its contact loss is round-off: 1e-12 of the work put in)
    if differ:
        problems.append(f"2 ranks: {differ}")
    return wrong("; ".join(problems)) if problems else ok()


@probe("surface-contacts", "SIGINT to a serial run after a checkpoint: the earlier result kept, the checkpoint "
                           "continues exactly", timeout=300)
def _interrupted(ctx):
    name = "m"
    out = ctx.folder / name
    r, _ = run_case(ctx, _drop(t_end=2e-5), out=name)   # (the earlier result, which the interrupted run must keep)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    ctx.keep(out)
    data = {**_drop(t_end=1.0), "name": "long"}   # (a million steps: interrupted long before its end)
    data["output"]["checkpoint_every"] = 200
    saved = lambda: bool(list(ctx.folder.glob(f".{name}.checkpoint-*/checkpoint/state.json")))  # noqa: E731
    case = ctx.folder / "long.yaml"
    case.write_text(yaml.safe_dump(data, sort_keys=False))
    r = ctx.run("run", case, "-q", "-o", out, signal_at=(saved, signal.SIGINT))
    if r.traceback:
        return Verdict("traceback", r.tail())
    lines = [line for line in r.lines() if line.startswith("fem-impact:")]
    if len(lines) != 1 or not lines[0].startswith("fem-impact: interrupted by "):
        return wrong(f"status {r.status}: {r.tail(4)}")
    if r.status != 128 + signal.SIGINT:
        return wrong(f"status {r.status}, expected {128 + signal.SIGINT}")
    kept = ctx.folder / f"{name}.checkpoint"
    if not (kept / "state.json").is_file() or f"--restart {kept}" not in lines[0]:
        return wrong(f"no checkpoint kept in {kept}, or not named: {lines[0]}")
    t0 = json.loads((kept / "state.json").read_text())["t"]
    data["solver"]["t_end"] = t0 + 100 * DT
    continued, bad = solved(ctx, data, "--restart", kept, out="continued")
    if bad:
        return bad
    whole, bad = solved(ctx, data, out="whole")
    if bad:
        return bad
    differ = _differ(whole, continued, tol=1e-12)
    return wrong(f"continued from the kept checkpoint: {differ}") if differ else ok(f"from t = {t0:.4g}")


# -- the sliding watch ------------------------------------------------------------------------------------------
def _watched(method: str):
    def body(ctx):
        r, out = run_case(ctx, _slide(method))
        return _stopped(ctx, r, out)
    return body


def _earlier_result(ctx):
    """A short drop written into the probe's folder and kept (a user's earlier result); its verdict if it failed."""
    r, out = run_case(ctx, _drop(t_end=2e-5))
    bad = ctx.succeeded(r)
    if not bad:
        ctx.keep(out)
    return bad


for _method in ("newmark", "modal"):
    probe("surface-contacts", f"sent sideways at 1 m/s, {_method} (rows of t = 0): stops at a quarter cell in one "
                              f"line, 'small sliding', nothing written")(_watched(_method))


@probe("surface-contacts", "sent sideways at 1 m/s into a folder holding an earlier result, VTK and checkpoints on: "
                           "the stop leaves the earlier result as it was")
def _watched_kept(ctx):
    bad = _earlier_result(ctx)
    if bad:
        return bad
    data = _slide()
    data["output"] = {"vtk": True, "every": 50, "checkpoint_every": 50}
    r, out = run_case(ctx, data)
    return _stopped(ctx, r, out, kept=True)


def _keeps_its_momentum(h: dict) -> list:
    """The frictionless sliding block's momentum, m v0 throughout: [] or the problem."""
    off = np.abs(h["upper.px"] - M_UPPER * V0).max()
    return [f"the sliding block's momentum off m v0 by {off:.3g}"] if off > 1e-9 * M_UPPER * V0 else []


def _continues_exactly(ctx, data: dict, end: float, what: str) -> Verdict:
    """``data``, run with checkpoints into ``first`` already, run to ``end`` whole and restarted from ``first``:
    the same history to 1e-12."""
    data["solver"]["t_end"] = end
    whole, bad = solved(ctx, data, out="whole")
    if bad:
        return bad
    continued, bad = solved(ctx, data, "--restart", ctx.folder / "first", out="continued")
    if bad:
        return bad
    differ = _differ(whole, continued, tol=1e-12)
    searches = _summary(ctx, "whole").get("surface_searches")
    return wrong(f"continued after {what}: {differ}") if differ else ok(f"{searches} searches")


@probe("surface-contacts", "sent sideways at 1 m/s, Moreau-Jean: stops at a quarter cell in one line, or (rows "
                           "found again as it slides) keeps its speed exactly, no force, no energy created")
def _watched_default(ctx):
    data = _slide("moreau_jean")
    r, out = run_case(ctx, data)
    if r.status != 0 or r.traceback:
        return _stopped(ctx, r, out)
    h = history(out)
    s = _summary(ctx)
    problems = _keeps_its_momentum(h)
    if np.abs(h[f"{NAME}.impulse"]).max() > 1e-9 * M_UPPER * V0:
        problems.append(f"impulses up to {np.abs(h[f'{NAME}.impulse']).max():.3g} on a block sliding freely")
    _budget(h, s, problems)
    return wrong("; ".join(problems)) if problems else ok(f"slid {V0 * h['t'][-1]:.3g} m without stopping")


@probe("surface-contacts", "sent sideways at 1 m/s, Moreau-Jean, split at 5 mm and restarted: as the whole run "
                           "(stopped at the same place in the same line, or continued exactly across its rows' search)")
def _watched_default_restart(ctx):
    data = _slide("moreau_jean", t_end=0.005)
    data["output"]["checkpoint_every"] = 10
    r, out = run_case(ctx, data, out="first")
    if r.status != 0 or r.traceback:   # (the rows of t = 0 kept: it stops before 5 mm)
        return _stopped(ctx, r, out)
    return _continues_exactly(ctx, data, 0.01, "5 mm")


def _carried(method: str = "moreau_jean", t_end: float = 0.01) -> dict:
    """The upper block sent along at 1 m/s while a support carries the lower one's base backward at
    0.5 m/s (supports: displacement; the contact's nodes not held): the rows slide at 1.5 m/s."""
    data = _slide(method, t_end=t_end)
    data["supports"] = [{"nodes": "base", "fix": "all", "displacement": ["-0.5*t", "0"]}]
    return data


@probe("surface-contacts", "sent sideways at 1 m/s over a lower block carried back at 0.5 m/s by its support "
                           "(Moreau-Jean): rows found again as they slide, the frictionless block keeps its speed, no "
                           "energy created")
def _carried_default(ctx):
    h, bad = solved(ctx, _carried())
    if bad:
        return bad
    s = _summary(ctx)
    problems = _keeps_its_momentum(h)
    if not s.get("surface_searches"):
        problems.append(f"slid {1.5 * h['t'][-1]:.3g} m on the lower block with no search")
    _budget(h, s, problems)
    return wrong("; ".join(problems)) if problems else ok(f"{s.get('surface_searches')} searches")


@probe("surface-contacts", "the same, split at 5 ms and restarted: as the whole run (the support's motion and the "
                           "rows' search across the checkpoint)")
def _carried_restart(ctx):
    data = _carried(t_end=0.005)
    data["output"]["checkpoint_every"] = 10
    _, bad = solved(ctx, data, out="first")
    return bad or _continues_exactly(ctx, data, 0.01, "5 ms")


@probe("surface-contacts", "the same on 2 MPI ranks: the serial history (to 1e-8)", timeout=300)
def _carried_two_ranks(ctx):
    data = _carried(t_end=0.004)
    a, bad = solved(ctx, data, out="serial")
    if bad:
        return bad
    b, bad = solved(ctx, data, mpi=2, out="mpi")
    if bad:
        return bad
    differ = _differ(a, b, tol=1e-8)   # (a search's geometry in another order of sums: 1e-10 of a gap's scale)
    return wrong(f"2 ranks: {differ}") if differ else ok()


@probe("surface-contacts", "the same with newmark (rows of t = 0): stops at a quarter cell of the relative slide in "
                           "one line, nothing written")
def _carried_newmark(ctx):
    r, out = run_case(ctx, _carried("newmark"))
    # (the support starts at 0.5 m/s at once: the lower face rings about it, so the relative slide is 1.5 t
    # only on average)
    return _stopped(ctx, r, out, when=CELL / 4 / 1.5, tolerance=0.15)


@probe("surface-contacts", "refused: a support moving the contact's surface (lower_top along y), in one line naming "
                           "the contact")
def _carried_surface(ctx):
    data = _slide("moreau_jean")
    data["supports"] = [{"nodes": "base", "fix": "all"},
                        {"nodes": "lower_top", "fix": ["y"], "displacement": ["1e-7*sin(200*t)"]}]
    return _refusal(ctx, data, "contacts[0].nodes", "a support prescribes")


@probe("surface-contacts", "sent sideways, restarted after 2 mm (newmark): the watch counts from t = 0, not from "
                           "the restart")
def _watched_restart(ctx):
    data = _slide(t_end=0.002)
    _, bad = solved(ctx, data, out="first")
    if bad:
        return bad
    data["solver"]["t_end"] = 0.01
    r, out = run_case(ctx, data, "--restart", ctx.folder / "first", out="continued")
    return _stopped(ctx, r, out)


@probe("surface-contacts", "sent sideways on 2 MPI ranks (newmark): one line, status not 0, no traceback",
       timeout=300)
def _watched_two_ranks(ctx):
    r, out = run_case(ctx, _slide(), mpi=2)
    return _stopped(ctx, r, out, mpi=True)


@probe("surface-contacts", "an initial displacement sliding the upper block 5 mm (newmark): stopped at t = 0 in one "
                           "line, or refused")
def _shifted(ctx):
    data = _drop("newmark", dt=1e-5, t_end=1e-3, velocity=(0.0, 0.0))
    data["initial"] = {"displacement": [{"body": "upper", "value": [0.005, 0.0]}]}
    r, out = run_case(ctx, data)
    if r.status == 2:
        verdict = ctx.refused(r, "initial", max_lines=1)
        return wrong(f"refused, yet {out} was written") if verdict.kind == "ok" and out.exists() else verdict
    return _stopped(ctx, r, out, when=0.0, tolerance=0.0)


# -- 3D: the boxes on node-to-segment rows -------------------------------------------------------------------
@probe("surface-contacts", "3D boxes (node-to-segment rows): the force p * 0.1 * 0.1 to 1e-10, the field within 5 %")
def _boxes_patch(ctx):
    data = _boxes(ctx)
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    want = P * WIDTH * WIDTH
    if abs(h[f"{NAME}.force"][-1] - want) > 1e-10 * want:
        problems.append(f"contact force {h[f'{NAME}.force'][-1]:.12g}, exact {want:.12g}")
    error = _field_error(ctx.folder / "out", dim=3)
    if error > 0.05:
        problems.append(f"the field off the exact one by {error:.3g} (3.5 % measured by tests/test_surface.py)")
    s = _summary(ctx)
    if s["constraints"] != 64 or s["energy_created"] != 0.0:
        problems.append(f"summary: constraints {s['constraints']} (64 nodes), energy_created {s['energy_created']}")
    return wrong("; ".join(problems)) if problems else ok(f"field within {error:.3g}")


@probe("surface-contacts", "3D boxes, the upper one dropped at 1 m/s: momentum by the impulses, no energy created")
def _boxes_drop(ctx):
    data = _boxes(ctx, loads=[], supports=[{"nodes": "base", "fix": "all"}],
                  initial={"velocity": [{"body": "upper", "value": [0.0, -V0, 0.0]}]},
                  solver={"method": "moreau_jean", "dt": DT, "t_end": 1e-4}, output={"vtk": False})
    h, bad = solved(ctx, data)
    if bad:
        return bad
    s = _summary(ctx)
    problems: list = []
    _dropped(h, s, problems, mass=M_UPPER / THICK * WIDTH)
    _budget(h, s, problems)
    return wrong("; ".join(problems)) if problems else ok()


@probe("surface-contacts", "3D boxes, the upper one sent along z at 1 m/s (newmark): stops at a quarter of the "
                           "lower face's cell")
def _boxes_slide(ctx):
    data = _boxes(ctx, loads=[], supports=[{"nodes": "base", "fix": "all"}],
                  initial={"velocity": [{"body": "upper", "value": [0.0, 0.0, V0]}]},
                  solver={"method": "newmark", "dt": 1e-5, "t_end": 0.01}, output={"vtk": False})
    r, out = run_case(ctx, data)
    return _stopped(ctx, r, out, when=WIDTH / 5 / 4 / V0)


# -- rigid bodies, Hertz, a node alone --------------------------------------------------------------------------
@probe("surface-contacts", "a rigid upper block dropped on the elastic lower one: momentum by the impulses, unturned, "
                           "no energy created, the drift within (1 - theta) dt v0")
def _rigid(ctx):
    data = _drop(t_end=2e-4, bodies={"upper": {"model": "rigid"}})
    h, bad = solved(ctx, data)
    if bad:
        return bad
    s = _summary(ctx)
    problems: list = []
    _dropped(h, s, problems, drift=0.5 * DT * V0)
    if np.abs(h["upper.omega"]).max() > 1e-9 * V0 / WIDTH:
        problems.append(f"the symmetric block turned: omega up to {np.abs(h['upper.omega']).max():.3g}")
    if np.abs(h["upper.vx"]).max() > 1e-9 * V0:
        problems.append(f"the frictionless block moved sideways: vx up to {np.abs(h['upper.vx']).max():.3g}")
    _budget(h, s, problems)
    return wrong("; ".join(problems)) if problems else ok(f"leaves at {h['upper.vy'][-1]:.4f} m/s")


R = 0.05


@probe("surface-contacts", "Hertz's cylinder (R / 100 cells): the force F / 2 to 1e-9, the half-width within a cell, "
                           "the peak pressure within 5 %")
def _hertz(ctx):
    h_cell, E, nu = R / 100, 210e9, 0.3
    e_star = E / (2.0 * (1.0 - nu ** 2))
    F = np.pi * e_star * (R / 10) ** 2 / (4 * R)
    a = np.sqrt(4 * F * R / (np.pi * e_star))
    p0 = 2 * F / (np.pi * a)
    data = {"name": "hertz", "mesh": {"file": str(_mesh(ctx, "hertz", "--cell", str(h_cell))),
                                      "hypothesis": "plane_strain"},
            "material": {"E": E, "rho": 7800.0, "nu": nu, "area": 1.0},
            "supports": [{"nodes": "base", "fix": ["y"]}, {"nodes": "axis", "fix": ["x"]}],
            "loads": [{"nodes": "lid", "traction": [0.0, float(-F / (2 * R))]}],
            "contacts": [_contact(nodes="rim", surface="top")],
            "solver": {"method": "moreau_jean", "theta": 1.0, "dt": 0.01, "t_end": 0.05},
            "output": {"vtk": True, "every": 5}}
    hist, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    if abs(hist[f"{NAME}.force"][-1] - F / 2) > 1e-9 * F / 2:
        problems.append(f"contact force {hist[f'{NAME}.force'][-1]:.12g}, F / 2 = {F / 2:.12g}")
    f = _last_frame(ctx.folder / "out", upper_above=0.0)
    rim = f["upper"] & (np.abs(np.hypot(f["x"][:, 0], f["x"][:, 1] - R) - R) < 1e-9 * R)
    x, force = f["x"][rim], f["contact_force"][rim]
    order = np.argsort(np.arctan2(x[:, 0], R - x[:, 1]))
    x, force = x[order], force[order]
    segment = np.linalg.norm(np.diff(x[:, :2], axis=0), axis=1)
    share = 0.5 * (np.concatenate([[0.0], segment]) + np.concatenate([segment, [0.0]]))
    p = np.linalg.norm(force[:, :2], axis=1) / share
    if np.any(force[:, 1] < -1e-9 * F):
        problems.append("a rim node pulled down")
    if abs(p.max() - p0) > 0.05 * p0:
        problems.append(f"peak pressure {p.max():.6g}, Hertz's {p0:.6g}")
    pressed, free = x[p > 0, 0], x[(p == 0) & (x[:, 0] > 0), 0]
    if not pressed.size or not free.size or not pressed.max() - h_cell <= a <= free.min() + h_cell:
        problems.append(f"the edge between {pressed.max() if pressed.size else None} and "
                        f"{free.min() if free.size else None}, Hertz's half-width {a:.6g}")
    return wrong("; ".join(problems)) if problems else ok(f"peak {p.max() / p0:.4f} p0")


@probe("surface-contacts", "a node group of one node (no edge) against the lower face: its node-to-segment row stops "
                           "the dropped block, no energy created")
def _one_node(ctx):
    data = _drop(mesh={"file": str(_mesh(ctx, "corner"))}, contacts=[_contact(nodes="upper_corner")])
    h, bad = solved(ctx, data)
    if bad:
        return bad
    s = _summary(ctx)
    problems: list = []
    _dropped(h, s, problems)
    if s["constraints"] != 1:
        problems.append(f"{s['constraints']} rows, one node")
    _budget(h, s, problems)
    return wrong("; ".join(problems)) if problems else ok()


# -- refusals ----------------------------------------------------------------------------------------------------
def _refused(change, *needles: str, mesh: str | None = None):
    def body(ctx):
        data = _patch(vtk=False)
        if mesh:
            data["mesh"] = {"file": str(_mesh(ctx, mesh))}
        contact = _contact()
        change(contact, data)
        data["contacts"] = [contact]
        return _refusal(ctx, data, *needles)
    return body


def _bar(contact, data):
    data.update(mesh={"shape": "bar", "length": 1.0, "cells": 10}, material={"E": 1.0, "rho": 1.0, "area": 1.0},
                supports=[], loads=[])
    data.pop("materials")
    contact.update(nodes="right", surface="left")


for _name, _change, _needles, _mesh_key in (
        ("a normal given", lambda c, d: c.update(normal=[0.0, -1.0]), ("contacts[0].normal",), None),
        ("a gap given", lambda c, d: c.update(gap=0.0), ("contacts[0].gap",), None),
        ("a motion given", lambda c, d: c.update(motion=["t", 0.0]), ("contacts[0].motion",), None),
        ("coupling: mean", lambda c, d: c.update(coupling="mean"), ("contacts[0].coupling",), None),
        ("the surface missing", lambda c, d: c.pop("surface"), ("contacts[0].surface", "required"), None),
        ("the surface its own node group", lambda c, d: c.update(surface="upper_bottom"),
         ("contacts[0].surface", "upper_bottom"), None),
        ("a surface of one node (no edge)", lambda c, d: c.update(surface="lower_corner"),
         ("contacts[0].surface", "lower_corner", "edge"), "corner"),
        ("type surface on the built-in 1D bar", _bar, ("contacts[0].type", "2D or 3D"), None),
):
    probe("surface-contacts", f"refused: {_name}")(_refused(_change, *_needles, mesh=_mesh_key))


@probe("surface-contacts", "refused: a surface group that does not exist, into a folder holding an earlier result "
                           "(kept as it was)")
def _nowhere(ctx):
    bad = _earlier_result(ctx)
    if bad:
        return bad
    data = _drop(t_end=2e-5, contacts=[_contact(surface="nowhere")])
    r, _ = run_case(ctx, data)
    return ctx.refused(r, "contacts[0].surface", "nowhere", max_lines=1)
