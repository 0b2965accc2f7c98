"""Surface contacts that slide: a step with rows found again by a search against a step with fixed pairs,
in one run.

The scene: two steel boxes 0.1 x 0.05 x 0.1 m, one on the other (meshes/two_blocks.py's boxes), ``n`` cells
across each (the same: their face nodes match), 3 up; the lower held at its base, the upper pressed on it by
gravity and sliding at ``v`` m/s; Moreau-Jean, frictionless. Its face has (n + 1)^2 rows (1681 at n = 40):

- ``pairs``: `type: pair` between the matched face nodes (node-to-node rows, fixed for the run: the
  faces do not follow the slide, which is what the surface contact is for; the cost is the reference);
- ``surface``: `type: surface`, node-to-segment rows on the same nodes, found again each time a row slid a
  quarter of a cell (``surface_searches`` in the summary), W rebuilt each time.

Prints per run: the setup time, ms a step of the loop, the searches and the ratio of the surface's step to the
pairs' (the issue's target, "a step at 1681 face rows with search costs at most 1.5 times a step with fixed
pairs"), and one search's cost in steps of the pairs' run.

    python benchmarks/surface_search.py [--cells 40] [--steps 200] [--speed 1.0] [--dt 1e-5]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the fem-impact command does

import fem_impact as fi  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
STEEL = {"E": 210e9, "rho": 7800.0, "nu": 0.3}


def boxes(folder: Path, cells: int) -> Path:
    spec = importlib.util.spec_from_file_location("two_blocks", ROOT / "meshes" / "two_blocks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.build_3d(folder / f"boxes{cells}.msh", cells, cells)


def case(mesh: Path, kind: str, steps: int, speed: float, dt: float) -> fi.Case:
    if kind == "pairs":
        contact = {"name": "face", "type": "pair", "nodes": ["upper_bottom", "lower_top"], "normal": [0.0, -1.0, 0.0]}
    else:
        contact = {"name": "face", "type": "surface", "nodes": "upper_bottom", "surface": "lower_top"}
    return fi.Case.from_dict({
        "name": f"boxes_{kind}", "mesh": {"file": str(mesh)}, "materials": {"lower": STEEL, "upper": STEEL},
        "supports": [{"nodes": "base", "fix": "all"}],
        "initial": {"velocity": [{"body": "upper", "value": [speed, 0.0, 0.0]}]},
        "loads": [{"body": "upper", "acceleration": [0.0, -9.81, 0.0]}],
        "contacts": [contact], "solver": {"dt": dt, "t_end": steps * dt}, "output": {"vtk": False, "every": steps}})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cells", type=int, default=40, help="cells across each face (default 40: 1681 rows)")
    parser.add_argument("--steps", type=int, default=200, help="steps of each run (default 200)")
    parser.add_argument("--speed", type=float, default=1.0, help="the upper box's speed, m/s (default 1)")
    parser.add_argument("--dt", type=float, default=1e-5, help="the step, s (default 1e-5)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        mesh = boxes(folder, args.cells)
        found = {}
        for kind in ("pairs", "surface"):
            s = fi.run(case(mesh, kind, args.steps, args.speed, args.dt), folder / kind).summary
            found[kind] = s
            print(f"{kind:8s} {s['constraints']} rows, {s['dofs']} unknowns: setup {s['setup_time_s']:.2f} s, "
                  f"{1e3 * s['loop_time_s'] / s['steps']:.2f} ms a step, searches {s.get('surface_searches', 0)}")
    pairs, surface = found["pairs"], found["surface"]
    step = pairs["loop_time_s"] / pairs["steps"]
    seconds = surface.get("surface_search_s", [])
    searches = len(seconds)
    ratio = (surface["loop_time_s"] / surface["steps"]) / step
    print(f"a step with searches / a step with fixed pairs, all told: {ratio:.2f}")
    if searches:
        first, rest = seconds[0], seconds[1:]
        plain = (surface["loop_time_s"] - sum(seconds)) / surface["steps"]
        each = sum(rest) / len(rest) if rest else first
        every = args.steps / searches
        print(f"the first search {first:.2f} s (the inverse's blocks on every dof the rows may reach: at setup), "
              f"the others {each:.3f} s each ({each / step:.0f} steps of the pairs' run); a step between searches "
              f"{1e3 * plain:.2f} ms ({plain / step:.2f} of the pairs')")
        print(f"a step with searches every {every:.0f} steps ({args.speed:g} m/s), the first search aside: "
              f"{(plain + each / every) / step:.2f} of the pairs' (target <= 1.5)")

if __name__ == "__main__":
    main()
