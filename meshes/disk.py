"""A disk (2D) for a rigid body that bounces: cases/bouncing_disk.yaml.

Builds, with the Gmsh Python API, a disk of radius ``radius`` centred at the origin, meshed in
triangles with ``points`` nodes on its rim (the first at (radius, 0), so one lies exactly under the
centre when ``points`` is a multiple of 4);

- physical group of dimension 2 (the body): ``disk``;
- physical group of dimension 1 (node group): ``rim``.

The file is written in MSH 4.1 format. Regenerate the committed mesh (radius 10 mm, 64 rim nodes) with

    .venv/bin/python meshes/disk.py
"""

from __future__ import annotations

import math
from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import (ScriptParser, add_named_groups, length_option, output_option, run_script,
                                       write_msh)

HERE = Path(__file__).resolve().parent
DEFAULT_OUTPUT = HERE / "disk.msh"


def build(radius: float = 0.01, points: int = 64, output: Path = DEFAULT_OUTPUT) -> Path:
    """Mesh the disk and write it to ``output``; returns the path written."""
    if not (radius > 0 and points >= 8 and points % 4 == 0):
        raise ValueError(f"need radius > 0 and points a multiple of 4, at least 8; got radius {radius:g}, "
                         f"points {points}")
    output = Path(output)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("disk")
        surface = gmsh.model.occ.addDisk(0.0, 0.0, 0.0, radius, radius)
        gmsh.model.occ.synchronize()
        rim = [tag for _, tag in gmsh.model.getBoundary([(2, surface)], oriented=False)]
        gmsh.option.setNumber("Mesh.MeshSizeMax", 2 * math.pi * radius / points)
        for curve in rim:   # (points nodes on the rim, evenly: the first at (radius, 0))
            gmsh.model.mesh.setTransfiniteCurve(curve, points + 1)
        add_named_groups(2, {"disk": [surface]})
        add_named_groups(1, {"rim": rim})
        gmsh.model.mesh.generate(2)
        write_msh(output)
    finally:
        gmsh.finalize()
    return output


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--radius", type=length_option(), default=0.01, help="radius (default 0.01)")
    parser.add_argument("--points", type=int, default=64, help="nodes on the rim, a multiple of 4 (default 64)")
    parser.add_argument("-o", "--output", type=output_option, default=DEFAULT_OUTPUT,
                        help=f"output .msh file (default {DEFAULT_OUTPUT.name} next to this script)")
    args, path = run_script(parser, lambda a: build(a.radius, a.points, a.output), argv)
    print(f"wrote {path}: a disk of radius {args.radius:g} with {args.points} nodes on its rim")


if __name__ == "__main__":
    main()
