"""A 2D block resting on a slab, for scenes that mix a rigid body with an elastic one (tests/test_mixed.py):
a block launched along the slab, or pressed on it.

Builds, with the Gmsh Python API (lengths in m), structured quadrilaterals of size ``h`` (default 1 cm):

- body ``slab``: 0.6 x 0.05 on y in [0, 0.05], in three thirds that share their nodes; node groups ``base``
  (y = 0) and ``top`` (y = 0.05, the middle third alone, x in [0.2, 0.4]);
- body ``block``: 0.2 x 0.05 above the middle third, 1e-6 over it; node groups ``bottom`` (its face on the
  slab, one node over each of ``top``'s: a node-to-node pair) and ``lid`` (its top).

    .venv/bin/python meshes/block_on_slab.py -o /tmp/slab.msh [--cell 0.005]
"""

from __future__ import annotations

from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import (ScriptParser, add_named_groups, length_option, output_option, run_script,
                                      structured_quads, write_msh)

GAP = 1e-6


def build(path: Path, h: float = 0.01) -> Path:
    """Mesh the slab and the block with cells of size ``h`` (m) and write them to ``path``; returns ``path``."""
    if not 0.0 < h <= 0.05:
        raise ValueError(f"h must be in (0, 0.05] m, got {h:g}")
    path = Path(path)
    gmsh.initialize(["", "-v", "0"])
    try:
        gmsh.model.add("block_on_slab")
        occ = gmsh.model.occ
        thirds = [(2, occ.addRectangle(x, 0.0, 0.0, 0.2, 0.05)) for x in (0.0, 0.2, 0.4)]
        slab = [tag for _, tag in occ.fragment(thirds, [])[0]]
        block = occ.addRectangle(0.2, 0.05 + GAP, 0.0, 0.2, 0.05)
        occ.synchronize()
        structured_quads((*slab, block), h)

        def edge(y, x0, x1):
            return [t for _, t in gmsh.model.getEntitiesInBoundingBox(x0 - 1e-7, y - 1e-7, -1, x1 + 1e-7, y + 1e-7, 1, 1)]

        add_named_groups(2, {"slab": slab, "block": [block]})
        add_named_groups(1, {"base": edge(0.0, 0.0, 0.6), "top": edge(0.05, 0.2, 0.4),
                             "bottom": edge(0.05 + GAP, 0.2, 0.4), "lid": edge(0.1 + GAP, 0.2, 0.4)})
        gmsh.model.mesh.generate(2)
        write_msh(path)
    finally:
        gmsh.finalize()
    return path


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-H", "--cell", type=length_option(), default=0.01, help="the cells' size (default 0.01 m)")
    parser.add_argument("-o", "--output", type=output_option, required=True, help="the .msh file to write")
    _, path = run_script(parser, lambda a: build(a.output, a.cell), argv)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
