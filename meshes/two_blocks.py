"""Two 2D blocks meshed apart, one on the other, with faces that do not match: the contact patch test
(tests/test_surface.py).

Builds, with the Gmsh Python API (lengths in m), structured quadrilaterals (or triangles):

- body ``lower``: 0.1 x 0.05 on y in [0, 0.05], ``n`` cells across; node groups ``base`` (y = 0) and
  ``lower_top`` (its face y = 0.05);
- body ``upper``: 0.1 x 0.05 on y in [0.05, 0.1], ``m`` cells across (7 for 5 by default: no node of
  one face over a node of the other but the ends); node groups ``upper_bottom`` (its face y = 0.05)
  and ``lid`` (y = 0.1);
- node group ``left``: the nodes on x = 0 of both blocks.

    .venv/bin/python meshes/two_blocks.py -o /tmp/blocks.msh [--cells 5 --upper 7] [--triangles]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import ScriptParser, add_named_groups, output_option, run_script, write_msh

WIDTH, HEIGHT = 0.1, 0.05


def build(path: Path, n: int = 5, m: int = 7, triangles: bool = False, up: int | None = None,
          span: tuple[float, float] = (0.0, WIDTH)) -> Path:
    """Mesh the two blocks, ``n`` and ``m`` cells across (``up`` cells up each, default as many as
    across), the upper one over x in ``span`` (default the lower one's width), and write them to
    ``path``; returns ``path``."""
    if n < 1 or m < 1:
        raise ValueError(f"the blocks need at least one cell across, got {n} and {m}")
    path = Path(path)
    gmsh.initialize(["", "-v", "0"])
    try:
        gmsh.model.add("two_blocks")
        occ = gmsh.model.occ
        lower = occ.addRectangle(0.0, 0.0, 0.0, WIDTH, HEIGHT)
        upper = occ.addRectangle(span[0], HEIGHT, 0.0, span[1] - span[0], HEIGHT)   # (not fragmented: meshed apart)
        occ.synchronize()
        for surface, cells in ((lower, n), (upper, m)):
            for _, curve in gmsh.model.getBoundary([(2, surface)], oriented=False):
                x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(1, curve)
                across = x1 - x0 > y1 - y0
                gmsh.model.mesh.setTransfiniteCurve(curve, (cells if across else (up or cells)) + 1)
            gmsh.model.mesh.setTransfiniteSurface(surface)
            if not triangles:
                gmsh.model.mesh.setRecombine(2, surface)

        def curves(surface, test):
            found = []
            for _, curve in gmsh.model.getBoundary([(2, surface)], oriented=False):
                box = gmsh.model.getBoundingBox(1, abs(curve))
                if test(box):
                    found.append(abs(curve))
            return found

        def at_y(y):
            return lambda b: abs(b[1] - y) < 1e-6 and abs(b[4] - y) < 1e-6   # (OCC pads its boxes)

        def at_x0(b):
            return abs(b[0]) < 1e-6 and abs(b[3]) < 1e-6

        add_named_groups(2, {"lower": [lower], "upper": [upper]})
        add_named_groups(1, {"base": curves(lower, at_y(0.0)), "lower_top": curves(lower, at_y(HEIGHT)),
                             "upper_bottom": curves(upper, at_y(HEIGHT)), "lid": curves(upper, at_y(2 * HEIGHT)),
                             "left": curves(lower, at_x0) + curves(upper, at_x0)})
        gmsh.model.mesh.generate(2)
        write_msh(path)
    finally:
        gmsh.finalize()
    return path


def build_3d(path: Path, n: int = 5, m: int = 7, up: int = 3, tetrahedra: bool = False) -> Path:
    """The two blocks as boxes 0.1 deep (z in [0, 0.1]), hexahedra (or ``tetrahedra``, six a hexahedron,
    triangles on the faces), ``n`` and ``m`` cells across x and z, ``up`` up: the same groups, ``left``
    on x = 0 and ``back`` on z = 0 of both."""
    if n < 1 or m < 1 or up < 1:
        raise ValueError(f"the blocks need at least one cell each way, got {n}, {m} and {up}")
    path = Path(path)
    gmsh.initialize(["", "-v", "0"])
    try:
        gmsh.model.add("two_blocks_3d")
        occ = gmsh.model.occ
        lower = occ.addBox(0.0, 0.0, 0.0, WIDTH, HEIGHT, WIDTH)
        upper = occ.addBox(0.0, HEIGHT, 0.0, WIDTH, HEIGHT, WIDTH)
        occ.synchronize()
        for volume, cells in ((lower, n), (upper, m)):
            boundary = gmsh.model.getBoundary([(3, volume)], combined=False, oriented=False)
            for _, curve in gmsh.model.getBoundary(boundary, combined=False, oriented=False):
                x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(1, abs(curve))
                gmsh.model.mesh.setTransfiniteCurve(abs(curve), (up if y1 - y0 > 1e-6 else cells) + 1)
            for _, face in boundary:
                gmsh.model.mesh.setTransfiniteSurface(face)
                if not tetrahedra:
                    gmsh.model.mesh.setRecombine(2, face)
            gmsh.model.mesh.setTransfiniteVolume(volume)
            if not tetrahedra:
                gmsh.model.mesh.setRecombine(3, volume)

        def faces(volume, axis, value):
            found = []
            for _, face in gmsh.model.getBoundary([(3, volume)], combined=False, oriented=False):
                box = gmsh.model.getBoundingBox(2, abs(face))
                if abs(box[axis] - value) < 1e-6 and abs(box[axis + 3] - value) < 1e-6:
                    found.append(abs(face))
            return found

        add_named_groups(3, {"lower": [lower], "upper": [upper]})
        add_named_groups(2, {"base": faces(lower, 1, 0.0), "lower_top": faces(lower, 1, HEIGHT),
                             "upper_bottom": faces(upper, 1, HEIGHT), "lid": faces(upper, 1, 2 * HEIGHT),
                             "left": faces(lower, 0, 0.0) + faces(upper, 0, 0.0),
                             "back": faces(lower, 2, 0.0) + faces(upper, 2, 0.0)})
        gmsh.model.mesh.generate(3)
        write_msh(path)
    finally:
        gmsh.finalize()
    return path


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cells", type=int, default=5, help="the lower block's cells across (default 5)")
    parser.add_argument("--upper", type=int, default=7, help="the upper block's cells across (default 7)")
    parser.add_argument("--triangles", action=argparse.BooleanOptionalAction, default=False,
                        help="triangles instead of quadrilaterals")
    parser.add_argument("--3d", dest="three_d", action="store_true", help="boxes 0.1 deep, hexahedra (3 cells up)")
    parser.add_argument("-o", "--output", type=output_option, required=True, help="the .msh file to write")
    _, path = run_script(parser, lambda a: (build_3d(a.output, a.cells, a.upper) if a.three_d
                                            else build(a.output, a.cells, a.upper, a.triangles)), argv)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
