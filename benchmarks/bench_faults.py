"""Bad-file fuzz at scale: mutated bags through every reader of the suite.

    python benchmarks/bench_faults.py [--files 3000]

Each mutated copy of a 14 s base bag (drive off, then a burst; 28 chunks) goes through the
record-by-record reader, the estimator's replay, the diagnosis's noise scan and the diagnosis data
path.  Reported: outcomes per reader (returned / refused with a clear, file-named error / FAIL),
how much of each damaged file was kept, and the time per file against reading the intact bag (the
baseline of the same run).  ``test_faults.py`` runs 1000 files with one heavy reader each.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from test.fuzz import base_bag, check, mutate, readers


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--files", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    logging.getLogger("piezofin_ros.bags.reader").setLevel(logging.ERROR)  # damage lines: thousands
    from piezofin_ros.bags import read_messages

    with tempfile.TemporaryDirectory() as d:
        directory = Path(d)
        base = base_bag(directory / "base.mcap")
        data = base.read_bytes()
        total = sum(1 for _ in read_messages(base))
        t0 = time.perf_counter()
        for name in readers():
            check(base, "intact", [name])
        intact_s = time.perf_counter() - t0
        rng = np.random.default_rng(args.seed)
        outcomes = []
        kept = []
        t0 = time.perf_counter()
        for k in range(args.files):
            kind, mutated = mutate(data, rng)
            path = directory / f"m{k}.mcap"
            path.write_bytes(mutated)
            n = 0
            with contextlib.suppress(Exception):  # refusals and failures are counted by check() below
                n = sum(1 for _ in read_messages(path, on_damage=None))
            kept.append((kind, n / total))
            outcomes += check(path, kind, list(readers()))
            path.unlink()
            if (k + 1) % 500 == 0:
                print(f"  {k + 1}/{args.files} files", file=sys.stderr, flush=True)
        per_file = (time.perf_counter() - t0) / args.files
    table = collections.Counter((o.reader, o.result.split(":")[0]) for o in outcomes)
    print(f"{args.files} mutated bags x {len(readers())} readers = {len(outcomes)} runs")
    for name in readers():
        ok, err, fail = (table[(name, r)] for r in ("ok", "error", "FAIL"))
        print(f"  {name:14s} returned {ok:5d}  refused with a clear error {err:5d}  FAIL {fail}")
    fails = [o for o in outcomes if o.result.startswith("FAIL")]
    for o in fails[:10]:
        print("  ", o)
    by_kind: dict[str, list[float]] = collections.defaultdict(list)
    for kind, frac in kept:
        by_kind[kind].append(frac)
    print("messages kept (median fraction of the intact bag) by damage:")
    print("  " + ", ".join(f"{k} {np.median(v):.2f}" for k, v in sorted(by_kind.items())))
    print(
        f"time per file (4 readers): {per_file * 1e3:.0f} ms; intact bag: {intact_s * 1e3:.0f} ms "
        f"(ratio {per_file / intact_s:.2f})"
    )
    print(f"slowest single run: {max(o.seconds for o in outcomes):.2f} s")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
