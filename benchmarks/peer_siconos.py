"""fem-impact's Moreau-Jean against Siconos' on the same matrices, step by step.

    .venv/bin/python benchmarks/peer_siconos.py [CASE.yaml] [--set KEY=VALUE ...]

Siconos 4.4 (Debian's python3-siconos, a peer to compare against, never a dependency) runs in
a separate /usr/bin/python3 process on the dense M, K, P, d0, load, U0, V0 of the case as
fem-impact builds them (serial). Both run Moreau-Jean with theta = 1/2 and Newton's impact law on
velocities (fem-impact's ``solver.level: velocity``): the histories of P U and of the energy
agree to round-off step by step until a row that drifted into the obstacle separates while
active, where the two laws differ by design (Siconos applies e to it, fem-impact e = 1 so that
the impulse does no positive work). Prints where, the differences and both wall times.
Default: the face of cases/face_on_stop.yaml coarsened to 20 cells (4 rows), Courant about 4.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = [str(ROOT / "cases" / "face_on_stop.yaml"), "--set", "mesh.cells=20", "--set", "solver.t_end=0.6"]

PEER = r'''
import json, sys, time
import numpy as np
import siconos.kernel as sk
d = np.load(sys.argv[1]); e = float(sys.argv[2])
M, K, Pt, d0, R = d["M"], d["K"], d["Pt"], d["d0"], d["R"]
dt, steps = float(d["dt"]), int(d["steps"])
ds = sk.LagrangianLinearTIDS(d["U0"].copy(), d["V0"].copy(), M)
ds.setKPtr(0.5 * (K + K.T))
ds.setFExtPtr(R.copy())
nsds = sk.NonSmoothDynamicalSystem(0.0, dt * steps)
nsds.insertDynamicalSystem(ds)
for j in range(d0.size):
    rel = sk.LagrangianLinearTIR(-Pt[:, j:j + 1].T.copy(), d0[j:j + 1].copy())
    nsds.link(sk.Interaction(sk.NewtonImpactNSL(e), rel), ds)
s = sk.TimeStepping(nsds, sk.TimeDiscretisation(0.0, dt), sk.MoreauJeanOSI(0.5), sk.LCP())
pu, energy = [Pt.T @ ds.q()], []
t0 = time.perf_counter()
for _ in range(steps):
    s.computeOneStep()
    q, v = ds.q(), ds.velocity()
    pu.append(Pt.T @ q)
    energy.append(0.5 * v @ M @ v + 0.5 * q @ K @ q)
    s.nextStep()
np.savez(sys.argv[3], pu=np.array(pu), energy=np.array(energy), wall=time.perf_counter() - t0)
'''


def main(argv):
    args = argv or DEFAULT
    case_path, rest = args[0], args[1:]
    sets = [rest[i + 1] for i in range(len(rest) - 1) if rest[i] == "--set"]
    sets += ["solver.method=moreau_jean", "solver.level=velocity", "output.vtk=false"]
    from mpi4py import MPI

    from fem_impact.config.case import load_case
    from fem_impact.integrators import Operators, integrate
    from fem_impact.build import make_integrator, model_and_constraints

    case = load_case(case_path, sets)
    if case.damping.alpha or case.damping.beta or any(c.stiffness for c in case.contacts):
        sys.exit("peer_siconos: the comparison covers undamped cases with rigid stops")
    model, cons = model_and_constraints(case, MPI.COMM_SELF)
    if model.load.varying:
        sys.exit("peer_siconos: the comparison covers constant loads")
    ops = Operators(model.M, model.K, model.C, model.load, cons.P_local, cons.d0, cons.restitution,
                    stop_compliance=cons.compliance)
    steps = int(round(case.solver.t_end / case.solver.dt))

    class Record:
        pu, energy = [], []

        def write(self, state):
            self.pu.append(state.normal_displacement.copy())
            self.energy.append(state.energy.total)

    record = Record()
    t0 = time.perf_counter()
    integrate(make_integrator(case, ops), model.U0, model.V0, case.solver.t_end, [record])
    ours = time.perf_counter() - t0

    def dense(A):
        return A.convert("dense").getDenseArray().copy()

    R = np.zeros(model.U0.getLocalSize())
    model.load.evaluate(0.0, R)
    with tempfile.TemporaryDirectory() as tmp:
        ops_file, out = Path(tmp) / "ops.npz", Path(tmp) / "peer.npz"
        np.savez(ops_file, M=dense(model.M), K=dense(model.K), Pt=np.asarray(cons.P_local.todense()), d0=cons.d0,
                 R=R, U0=model.U0.array_r.copy(), V0=model.V0.array_r.copy(), dt=case.solver.dt, steps=steps)
        script = Path(tmp) / "peer.py"
        script.write_text(PEER)
        proc = subprocess.run(["/usr/bin/python3", str(script), str(ops_file), str(cons.restitution[0]), str(out)],
                              capture_output=True, text=True)
        if proc.returncode:
            sys.exit(f"peer_siconos: Siconos did not run ({proc.stderr.strip().splitlines()[-1:]}); "
                     "install Debian's python3-siconos to compare")
        peer = np.load(out)
        pu_peer, e_peer, wall = peer["pu"], peer["energy"], float(peer["wall"])
    pu_ours, e_ours = np.array(record.pu), np.array(record.energy[1:])
    scale_u = max(np.abs(pu_ours).max(), np.abs(cons.d0).max())
    diff = np.abs(pu_ours - pu_peer).max(axis=1) / scale_u
    first = int(np.argmax(diff > 1e-9)) if (diff > 1e-9).any() else len(diff)
    print(json.dumps({
        "case": case.name, "dofs": model.dofs, "rows": cons.p, "steps": steps, "dt": case.solver.dt,
        # Identical to round-off up to the first step where a row that drifted into the obstacle
        # separates while active: Siconos applies e to it (its impulse then does positive work),
        # fem-impact takes e = 1 there (work zero; see moreau_jean.py).
        "steps_identical": first, "max_gap_difference_relative_before": float(diff[:first].max(initial=0.0)),
        "max_gap_difference_relative": float(diff.max()),
        "max_energy_difference_relative": float(np.abs(e_ours - e_peer).max() / max(np.abs(e_peer).max(), 1e-300)),
        "fem_impact_loop_s": ours, "siconos_loop_s": wall,
        "max_energy_fem_impact": float(e_ours.max()), "max_energy_siconos": float(e_peer.max())}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
