"""Two collinear 1D bars separated by a gap, for node-to-node pair contact (cases/two_bars.yaml).

Builds, with the Gmsh Python API:

- curve ``bar_a`` on [0, L] and curve ``bar_b`` on [L + gap, 2L + gap] along x, each cut
  into ``cells`` equal elements (transfinite curves); they share no node, so they are two
  free bodies that interact only through the contact defined in the case file;
- physical groups of dimension 1 (bodies): ``bar_a``, ``bar_b``;
- physical groups of dimension 0 (node groups): ``a_left`` (x = 0), ``a_right`` (x = L),
  ``b_left`` (x = L + gap), ``b_right`` (x = 2L + gap).

The file is written in MSH 4.1 format. Regenerate the committed mesh (L = 1, gap = 0.1,
100 cells per bar) with

    .venv/bin/python meshes/two_bars.py

or another one with e.g.

    .venv/bin/python meshes/two_bars.py --length 2 --gap 0.05 --cells 400 -o /tmp/bars.msh
"""

from __future__ import annotations

from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import (ScriptParser, add_named_groups, length_option, output_option, run_script,
                                       write_msh)

HERE = Path(__file__).resolve().parent
DEFAULT_OUTPUT = HERE / "two_bars.msh"


def build(length: float = 1.0, gap: float = 0.1, cells: int = 100, output: Path = DEFAULT_OUTPUT) -> Path:
    """Mesh the two bars and write them to ``output``; returns the path written."""
    if not (length > 0 and gap >= 0 and cells >= 1):
        raise ValueError(f"need length > 0, gap >= 0 and cells >= 1; got length {length:g}, gap {gap:g}, "
                         f"cells {cells}")
    if gap == 0:
        raise ValueError("gap = 0 would make the two bars share a point; give gap > 0")
    output = Path(output)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("two_bars")
        geo = gmsh.model.geo
        x = [0.0, length, length + gap, 2.0 * length + gap]
        points = [geo.addPoint(xi, 0.0, 0.0) for xi in x]
        bar_a = geo.addLine(points[0], points[1])
        bar_b = geo.addLine(points[2], points[3])
        for curve in (bar_a, bar_b):
            # cells + 1 nodes, uniformly spaced.
            geo.mesh.setTransfiniteCurve(curve, cells + 1)
        geo.synchronize()

        add_named_groups(1, {"bar_a": [bar_a], "bar_b": [bar_b]})
        add_named_groups(0, {name: [p] for name, p in zip(("a_left", "a_right", "b_left", "b_right"), points,
                                                          strict=True)})
        gmsh.model.mesh.generate(1)
        write_msh(output)
    finally:
        gmsh.finalize()
    return output


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--length", type=length_option(), default=1.0, help="length L of each bar (default 1)")
    parser.add_argument("--gap", type=length_option(), default=0.1, help="distance between the bars (default 0.1)")
    parser.add_argument("--cells", type=int, default=100, help="elements per bar (default 100)")
    parser.add_argument("-o", "--output", type=output_option, default=DEFAULT_OUTPUT,
                        help=f"output .msh file (default {DEFAULT_OUTPUT.name} next to this script)")
    args, path = run_script(parser, lambda a: build(a.length, a.gap, a.cells, a.output), argv)
    print(f"wrote {path}: two bars of length {args.length:g}, gap {args.gap:g}, {args.cells} cells each")


if __name__ == "__main__":
    main()
