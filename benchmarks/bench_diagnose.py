"""Benchmark of `piezofin diagnose` on "real" datasets whose cause the tool is not told.

Each dataset is the time-domain simulator with hidden effects (``diagnosis.synthetic``): one
in-library effect (every effect of the library the same number of times, random strength and fin),
two in-library effects, one effect *outside* the library, or none.  The tool runs blind.

Reported: top-1 attribution accuracy on single in-library effects (goal >= 90 %), the rate of
confident wrong answers on out-of-library cases (goal <= 10 %), both effects named for pairs, "no
gap" on clean data, the median held-out shrink of the gap (goal >= 80 %) and the time per dataset.

Then the blind generator (``diagnosis.blind``): effects written in forms the library lacks (instruments,
time, missing physics, interference), ``--blind`` datasets each, and as many clean ones; scored by the
family named (the chosen effects', the least-bad candidate's stated family, or a reversed sensor).

    python benchmarks/bench_diagnose.py [--per-effect 4] [--outside 20] [--double 14] [--clean 6] [--blind 4]
                                        [--workers 2] [--ray ADDRESS]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from piezofin_ros import workers
from piezofin_ros.diagnosis.attribute import diagnose
from piezofin_ros.diagnosis.blind import BLIND, BlindCase, named_family, random_blind, simulate_blind
from piezofin_ros.diagnosis.synthetic import IN_LIBRARY, Case, draw_strength, random_case, simulate_case
from piezofin_ros.physics.fin import load_fin


def cases(
    per_effect: int, outside: int, double: int, clean: int, seed: int, blind: int = 0
) -> list[tuple[str, Case | BlindCase]]:
    rng = np.random.default_rng(seed)
    out: list[tuple[str, Case | BlindCase]] = []
    for name in IN_LIBRARY:
        for _ in range(per_effect):
            c = random_case(rng, "single")
            out.append(("single", Case(c.fin, {name: draw_strength(name, rng)}, c.seed)))
    out += [("outside", random_case(rng, "outside")) for _ in range(outside)]
    out += [("double", random_case(rng, "double")) for _ in range(double)]
    out += [
        ("clean", Case(str(rng.choice(["M8507-P1", "M8514-P1", "M8528-P1"])), {}, int(rng.integers(2**31))))
        for _ in range(clean)
    ]
    brng = np.random.default_rng(seed + 1)
    for name in BLIND:
        out += [("blind", random_blind(brng, name)) for _ in range(blind)]
    out += [("blind", random_blind(brng, "")) for _ in range(blind)]  # clean, in the blind generator
    return out


def run_blind(case: BlindCase) -> dict[str, object]:
    trials = simulate_blind(case)
    t0 = time.perf_counter()
    d = diagnose(trials, load_fin(case.fin))
    elapsed = time.perf_counter() - t0
    fam = named_family(d)
    truth = case.family
    named_families = set((fam or "").split(" + ")) - {""}
    return {
        "kind": "blind",
        "fin": case.fin,
        "truth": {case.effect or "clean": case.strength},
        "family": truth,
        "verdict": d.verdict,
        "named": list(d.named),
        "named_family": fam,
        "confident": d.confident,
        "ambiguous_with": [c.label for c in d.ambiguous],
        # the right family named: by the chosen effect(s) (alone), the least-bad candidate's stated
        # family, or the data check (a reversed sensor); "no gap" where there is none to find
        "correct": (d.verdict == "no gap" and fam is None) if truth is None else fam == truth,
        "family_in_named": truth is not None and truth in named_families,
        "false": truth is None and d.verdict == "explained",
        "shrink": d.shrink if d.verdict == "explained" else None,
        "best_shrink": float(1 - np.sqrt(d.candidates[0].chi2_test / max(d.nominal.chi2_test, 1e-300))),
        "seconds": elapsed,
    }


def run(item: tuple[str, Case | BlindCase]) -> dict[str, object]:
    kind, case = item
    if isinstance(case, BlindCase):
        return run_blind(case)
    gen = simulate_case(case)
    t0 = time.perf_counter()
    d = diagnose(gen.trials, load_fin(case.fin))
    elapsed = time.perf_counter() - t0
    truth = set(case.effects)
    named = set(d.named)
    return {
        "kind": kind,
        "fin": case.fin,
        "truth": case.effects,
        "verdict": d.verdict,
        "named": list(d.named),
        "confident": d.confident,
        "ambiguous_with": [c.label for c in d.ambiguous],
        "correct": named == truth if kind != "outside" else None,
        "top1": kind == "single" and d.named[:1] == tuple(case.effects),
        "confident_wrong": kind == "outside" and d.confident,
        "shrink": d.shrink if d.verdict == "explained" else None,
        "best_shrink": float(1 - np.sqrt(d.candidates[0].chi2_test / max(d.nominal.chi2_test, 1e-300))),
        "seconds": elapsed,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-effect", type=int, default=4)
    ap.add_argument("--outside", type=int, default=20)
    ap.add_argument("--double", type=int, default=14)
    ap.add_argument("--clean", type=int, default=6)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--blind", type=int, default=4, help="datasets per blind effect (and clean)")
    workers.add_arguments(ap)
    ap.add_argument("--json", help="write every result here")
    args = ap.parse_args()
    items = cases(args.per_effect, args.outside, args.double, args.clean, args.seed, args.blind)
    t0 = time.perf_counter()
    results = workers.run_parsed(run, items, args, lambda item: f"{item[0]} {item[1].fin}", prefix="  ")
    for j, r in enumerate(results):  # in the datasets' order, on any number of workers
        mark = "ok" if r["correct"] or (r["kind"] == "outside" and not r["confident"]) else "MISS"
        said = ",".join(r["named"]) or str(r.get("named_family") or "")  # type: ignore[arg-type]
        print(
            f"[{j + 1:3d}/{len(items)}] {r['kind']:<7} {r['fin']:<9} {','.join(r['truth']) or '-':<45} -> "  # type: ignore[arg-type]
            f"{r['verdict']:<11} {said:<45} {mark} ({r['seconds']:.1f} s)",
            flush=True,
        )
    wall = time.perf_counter() - t0

    def pick(kind: str) -> list[dict[str, object]]:
        return [r for r in results if r["kind"] == kind]

    single, outside, double, clean = pick("single"), pick("outside"), pick("double"), pick("clean")
    blind = pick("blind")
    shrinks = [
        float(r["shrink"])  # type: ignore[arg-type]
        for r in results
        if r["shrink"] is not None and r["kind"] in ("single", "double")
    ]
    print()
    print(
        f"datasets: {len(results)} ({len(single)} single, {len(double)} double, {len(outside)} outside, {len(clean)} clean); {wall:.0f} s wall"  # noqa: E501
    )
    print(
        f"top-1 on single in-library effects: {sum(bool(r['top1']) for r in single)}/{len(single)} = {np.mean([bool(r['top1']) for r in single]):.0%}"  # noqa: E501
    )
    print(
        f"out-of-library, confident wrong answer: {sum(bool(r['confident_wrong']) for r in outside)}/{len(outside)}"  # noqa: E501
        f" (said unexplained: {sum(r['verdict'] == 'unexplained' for r in outside)})"
    )
    print(f"pairs, both effects named: {sum(bool(r['correct']) for r in double)}/{len(double)}")
    print(f"clean data, 'no gap': {sum(r['verdict'] == 'no gap' for r in clean)}/{len(clean)}")
    print(
        f"median held-out shrink (explained in-library cases): {np.median(shrinks):.1%} (min {np.min(shrinks):.1%}, n={len(shrinks)})"  # noqa: E501
    )
    if blind:
        visible = [r for r in blind if r["family"] is not None]
        empty = [r for r in blind if r["family"] is None]
        bsh = [float(r["best_shrink"]) for r in visible]  # type: ignore[arg-type]
        print(
            "blind generator (forms outside the library): right family "
            f"{sum(bool(r['correct']) for r in visible)}/{len(visible)} = "
            f"{np.mean([bool(r['correct']) for r in visible]):.0%} (in the named set: "
            f"{sum(bool(r['family_in_named']) for r in visible)}); median shrink of the least-bad candidate "
            f"{np.median(bsh):.1%}"
        )
        print(
            "blind clean or interference only: 'no gap' "
            f"{sum(bool(r['correct']) for r in empty)}/{len(empty)}; "
            f"an effect named where none is: {sum(bool(r['false']) for r in empty)}"
        )
        wrong = [r for r in visible if not r["correct"] and r["verdict"] == "explained"]
        print(f"blind, a wrong family named with a verdict 'explained': {len(wrong)}/{len(visible)}")
        for name in BLIND:
            rs = [r for r in blind if name in r["truth"]]  # type: ignore[operator]
            print(
                f"  {name:<24} {sum(bool(r['correct']) for r in rs)}/{len(rs)}  "
                + "; ".join(f"{r['verdict']}: {','.join(r['named']) or r['named_family'] or '-'}" for r in rs)  # type: ignore[arg-type]
            )
    secs = [float(r["seconds"]) for r in results]  # type: ignore[arg-type]
    print(f"diagnosis time per 33-trial dataset: median {np.median(secs):.1f} s, max {np.max(secs):.1f} s")
    print()
    print(f"{'effect':<26} {'n':>2} {'top-1':>6} {'ambiguous':>9} {'median shrink':>14}")
    for name in IN_LIBRARY:
        rs = [r for r in single if name in r["truth"]]  # type: ignore[operator]
        sh = [float(r["shrink"]) for r in rs if r["shrink"] is not None]  # type: ignore[arg-type]
        print(
            f"{name:<26} {len(rs):>2} {sum(bool(r['top1']) for r in rs):>6} {sum(bool(r['ambiguous_with']) for r in rs):>9} "  # noqa: E501
            f"{(f'{np.median(sh):.0%}' if sh else '-'):>14}"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
