"""Do two commits give the same histories? Every case in cases/ and every run the default test tier
makes, on both, compared column by column.

    python tools/same_histories.py OLD NEW                 # e.g. main~5 HEAD; both are git revisions
    python tools/same_histories.py OLD NEW --cases-only    # the case files only (a few minutes)
    python tools/same_histories.py OLD NEW --tests-only -k test_methods   # pytest options pass on
    python tools/same_histories.py OLD NEW --keep DIR [--compare-only]    # keep the runs, compare again

Each revision is checked out into a temporary worktree and run with this interpreter (the
project's virtual environment) and that worktree first on the path. Every run records its
history rows unrounded (``FEM_IMPACT_RECORD``: ``HistoryWriter``), labelled by the test that
made it (or by the case file). Runs are matched within a label by case name, columns and length;
a column agrees when identical, or within ``--tolerance`` (default 1e-12) of its scale (its
largest magnitude in the old run). Exit status 0 when every run of the old revision has an
agreeing run in the new one.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def checkout(revision: str, where: Path) -> Path:
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(where), revision], check=True)
    return where


def record(tree: Path, out: Path, cases_only: bool, tests_only: bool, pytest_args: list[str]) -> None:
    env = {**os.environ, "PYTHONPATH": str(tree), "FEM_IMPACT_RECORD": str(out)}
    env.pop("PYTEST_CURRENT_TEST", None)
    for case in [] if tests_only else sorted((tree / "cases").glob("*.yaml")):
        print(f"  {case.name}", flush=True)
        subprocess.run([sys.executable, "-m", "fem_impact", "run", str(case), "-q", "--set", "output.vtk=false",
                        "-o", str(out.parent / "runs" / case.stem)], cwd=tree, env=env, check=True)
    if not cases_only:
        print("  the default test tier", flush=True)
        subprocess.run([sys.executable, "-m", "pytest", "-q", "-m", "not slow", "-p", "no:cacheprovider",
                        *pytest_args], cwd=tree, env=env)


def runs(folder: Path) -> dict[str, list[tuple[str, list[str], np.ndarray]]]:
    """label -> [(case name, columns, rows)]."""
    found = defaultdict(list)
    for path in sorted(folder.glob("*/*.npz")):
        with np.load(path) as f:
            found[path.parent.name].append((path.stem.rsplit("-", 2)[0], list(f["columns"]), f["data"]))
    return found


ENERGY_COLUMNS = {"kinetic", "strain", "external_work", "damping_loss", "impact_loss", "contact_loss", "energy_error",
                  "scheme_energy", "friction_loss"}


def difference(a: np.ndarray, b: np.ndarray, columns: list[str] | None = None) -> float:
    """The largest difference of a column pair relative to the old column's scale (0: identical).

    The energy columns share one scale, the largest of them: a strain energy that is round-off in a
    rigid motion (1e-18 J beside 0.5 J of kinetic energy) or the balance's residual is measured
    against the run's energy, not against itself."""
    if a.size == 0:
        return 0.0
    scale = np.nanmax(np.abs(a), axis=0)
    if columns is not None:
        energy = np.array([c in ENERGY_COLUMNS for c in columns])
        if energy.any():
            scale[energy] = np.nanmax(scale[energy])
    scale[~(scale > 0)] = 1.0
    with np.errstate(invalid="ignore"):
        d = np.abs(a - b) / scale
    d[np.isnan(a) & np.isnan(b)] = 0.0
    return float(np.nanmax(d, initial=0.0)) if not np.isnan(d).any() else np.inf


def compare(old: dict, new: dict, tolerance: float) -> int:
    identical = close = 0
    problems = []
    for label, old_runs in old.items():
        candidates = list(new.get(label, []))
        for name, columns, data in old_runs:
            best, best_i, worst_column = np.inf, None, None
            for i, (n, c, d) in enumerate(candidates):
                if n != name or c != columns or d.shape != data.shape:
                    continue
                diff = difference(data, d, columns)
                if diff < best:
                    best, best_i = diff, i
                    per = [difference(data[:, [j]], d[:, [j]]) for j in range(len(columns))]
                    worst_column = columns[int(np.argmax(per))]
            if best_i is None:
                problems.append(f"{label}: {name}: no run with the same columns and length in the new revision")
                continue
            candidates.pop(best_i)
            if best == 0.0:
                identical += 1
            elif best <= tolerance:
                close += 1
            else:
                problems.append(f"{label}: {name}: {worst_column} differs by {best:.3g} of its scale")
    total = sum(len(r) for r in old.values())
    print(f"{total} runs: {identical} identical, {close} within {tolerance:g} of each column's scale, "
          f"{len(problems)} not")
    for line in problems:
        print("  " + line)
    return 1 if problems else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old")
    parser.add_argument("new")
    parser.add_argument("--cases-only", action="store_true")
    parser.add_argument("--tests-only", action="store_true")
    parser.add_argument("--tolerance", type=float, default=1e-12)
    parser.add_argument("--keep", type=Path, help="keep the recorded runs in this folder (and compare again "
                                                  "from it with --compare-only)")
    parser.add_argument("--compare-only", action="store_true", help="compare the runs recorded in --keep")
    args, pytest_args = parser.parse_known_args(argv)
    tmp = args.keep or Path(tempfile.mkdtemp(prefix="same-histories-"))
    if not args.compare_only:
        for side, revision in (("old", args.old), ("new", args.new)):
            print(f"{side}: {revision}", flush=True)
            tree = tmp / side / "tree"
            try:
                record(checkout(revision, tree), tmp / side / "recorded", args.cases_only, args.tests_only,
                       pytest_args)
            finally:
                if tree.exists():
                    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)
    print(f"runs recorded in {tmp}")
    return compare(runs(tmp / "old" / "recorded"), runs(tmp / "new" / "recorded"), args.tolerance)


if __name__ == "__main__":
    sys.exit(main())
