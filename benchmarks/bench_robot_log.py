"""The diagnosis on what a 1 kHz robot logs: jittered stamps, lost packets, encoder q and τ_J only (issue #12).

    .venv/bin/python benchmarks/bench_robot_log.py [--seeds 3] [--workers 2]

Twin cases of the gap benchmark (:mod:`proprio.gap_benchmark.run`, ``--twin``) with the twin's logger at 1 kHz,
host-stamp jitter σ = 0.1 ms (steps 0.7–1.3 ms) and 2 % of the samples followed by a burst of 1–7 lost ones (steps
up to 8 ms): a null case (friction in the data and in the model) and a friction-withheld case per seed. Prints per
case what was named (physical effects and, apart, the data-path candidates), the held-out RMS after the last step
and the floor (the same model on held-out data made without the withheld effect), and the checks: the null case names
nothing, friction is named first and no processing candidate is ever named, the final RMS within 15 % of the floor.
"""
from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from proprio.gap_benchmark.run import run_case
from proprio.gap_benchmark.cases import BenchmarkCase

LOGGER = (("rate_hz", 1000.0), ("stamp_jitter_ms", 0.1), ("dropout_prob", 0.02), ("dropout_max_samples", 7))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="cases per kind (default 3)")
    ap.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    args = ap.parse_args()
    cases = []
    for k in range(args.seeds):
        seed = 1000 + 17 * k
        cases.append(BenchmarkCase(f"null#{k}", (), 1.0, seed, modelled=("viscous_coulomb",), twin=True,
                                   logger=LOGGER))
        cases.append(BenchmarkCase(f"friction#{k}", ("viscous_coulomb",), 1.0, seed, twin=True, logger=LOGGER))
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        results = list(pool.map(run_case, cases))
    print(f"1 kHz robot log (jitter 0.1 ms, 2 % lost bursts of 1–7 samples), {len(cases)} twin cases in "
          f"{time.perf_counter() - t0:.0f} s")
    print(f"{'case':<12} {'named (physical)':<40} {'data path':<22} {'final':>7} {'floor':>7} {'ratio':>6}  check")
    ok_all = True
    for r in results:
        if r.error:
            print(f"{r.case.name:<12} ERROR {r.error}")
            ok_all = False
            continue
        if r.case.withheld:
            ratio = r.final_rms / r.floor_rms
            ok = bool(r.top) and r.top[0] == "viscous_coulomb" and not r.processing and abs(ratio - 1) <= 0.15
        else:
            ratio = float("nan")
            ok = not r.steps and not r.processing
        ok_all &= ok
        print(f"{r.case.name:<12} {' > '.join(r.steps) or '(nothing)':<40} {', '.join(r.processing) or '-':<22} "
              f"{r.final_rms:7.3f} {r.floor_rms:7.3f} {ratio:6.3f}  {'ok' if ok else 'FAIL'}")
    print("all checks pass" if ok_all else "some checks fail")
    ratios = [r.final_rms / r.floor_rms for r in results if r.case.withheld and not r.error]
    if ratios:
        print(f"final / floor RMS: {np.min(ratios):.3f}–{np.max(ratios):.3f}")


if __name__ == "__main__":
    main()
