"""``python -m tools.probes [-k CLASS] [-j N] [-v] [--list]``: run the probe classes, print their counts."""

from __future__ import annotations

import argparse
import sys
import time

from . import load, run_probes


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.probes", description=__doc__)
    parser.add_argument("-k", dest="pattern", default=None, help="only the classes whose name holds this text")
    parser.add_argument("-j", dest="workers", type=int, default=2, help="probes at a time (default 2)")
    parser.add_argument("-v", dest="verbose", action="store_true", help="print every verdict, not only failures")
    parser.add_argument("--list", action="store_true", help="list the probes and stop")
    parser.add_argument("--keep", default=None, metavar="DIR", help="run in DIR and keep every probe's folder")
    args = parser.parse_args(argv)
    probes = load(args.pattern)
    if args.list:
        for p in probes:
            print(f"{p.cls}: {p.name}")
        print(f"{len(probes)} probes")
        return 0
    if not probes:
        print(f"no probe class holds {args.pattern!r}", file=sys.stderr)
        return 2

    def report(p, verdict, seconds):
        if args.verbose or verdict.kind != "ok":
            print(f"[{verdict.kind:>9}] {p.cls}: {p.name} ({seconds:.1f} s) {verdict.detail}", flush=True)

    start = time.monotonic()
    result = run_probes(probes, workers=args.workers, folder=args.keep, report=report)
    print(result.table())
    print(f"{len(probes)} probes in {time.monotonic() - start:.0f} s" +
          (f"; folders of the failed ones in {result.folder}" if result.failures() else ""))
    return 1 if result.failures() else 0


if __name__ == "__main__":
    sys.exit(main())
