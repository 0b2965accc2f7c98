"""A scene built from a Gmsh model in Python: an aluminium block (2D, plane stress) dropped on a
rigid floor under gravity. Gmsh writes the mesh (a body ``block`` and a node group ``bottom``), a
case given as a dict uses it, and the run checks the momentum balance along y: the floor's total
impulse equals the change of the block's momentum plus the impulse of its weight.

    python examples/gmsh_scene.py            # element size 2.5 mm
    python examples/gmsh_scene.py --coarse   # 10 mm (what the test suite runs)
"""

import sys
import tempfile
from pathlib import Path

import gmsh

import fem_impact
from fem_impact.fem.gmsh_utils import add_named_groups, write_msh

WIDTH, HEIGHT = 0.10, 0.05            # m
E, RHO, NU, THICKNESS = 70e9, 2700.0, 0.33, 0.01   # Pa, kg/m^3, -, m
G, V0, GAP = 9.81, 0.5, 1e-3          # m/s^2, m/s (downward), m


def block_mesh(path: Path, size: float) -> Path:
    """The block as a Gmsh model: a rectangle, its bottom edge named for the contact."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("block")
        surface = gmsh.model.occ.addRectangle(0.0, 0.0, 0.0, WIDTH, HEIGHT)
        gmsh.model.occ.synchronize()
        bottom = [tag for dim, tag in gmsh.model.getBoundary([(2, surface)], oriented=False)
                  if abs(gmsh.model.occ.getCenterOfMass(1, tag)[1]) < 1e-12]
        add_named_groups(2, {"block": [surface]})
        add_named_groups(1, {"bottom": bottom})
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", size)
        gmsh.model.mesh.generate(2)
        return write_msh(path)
    finally:
        gmsh.finalize()


def main(coarse: bool = False) -> dict:
    with tempfile.TemporaryDirectory() as folder:
        mesh = block_mesh(Path(folder) / "block.msh", 0.01 if coarse else 0.0025)
        case = fem_impact.Case.from_dict({
            "mesh": {"file": str(mesh), "dim": 2},
            "material": {"E": E, "rho": RHO, "nu": NU, "area": THICKNESS},
            "initial": {"velocity": [0.0, -V0]},
            "loads": [{"body": "block", "acceleration": [0.0, -G]}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0],
                          "gap": GAP}],
            # c = 5.1 km/s: 2 us is a Courant number of 1 at 10 mm, 4 at 2.5 mm (Moreau-Jean holds at any step).
            "solver": {"dt": 2e-6, "t_end": 3e-3},
            "output": {"probes": {"centre": [WIDTH / 2, HEIGHT / 2]}},
        })
        result = fem_impact.run(case)
    h, s = result.history, result.summary
    mass = s["body_mass"]["block"]
    impulse = h["floor.impulse"].sum()
    momentum_change = h["block.py"][-1] - h["block.py"][0]
    weight_impulse = -mass * G * h["t"][-1]
    print(f"{s['dofs']} unknowns, {s['constraints']} contact rows, {s['steps']} steps in {s['wall_time_s']:.2f} s")
    print(f"floor impulse {impulse:.6g} N s = change of momentum {momentum_change:.6g} - weight impulse "
          f"{weight_impulse:.6g} (residual {impulse - momentum_change + weight_impulse:.2g} N s)")
    print(f"the block leaves at a mean {h['block.py'][-1] / mass:.4g} m/s (arrived at {-V0} m/s), still ringing: "
          f"its centre moves at {h['centre.vy'][-1]:.4g} m/s; max E / (E0 + W_ext) = {s['max_energy_ratio']:.4f}")
    return {"impulse": impulse, "momentum_change": momentum_change, "weight_impulse": weight_impulse,
            "mass": mass, "max_energy_ratio": s["max_energy_ratio"], "rows": s["constraints"]}


if __name__ == "__main__":
    main(coarse="--coarse" in sys.argv)
