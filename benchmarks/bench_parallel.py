"""Speed-up of ``proprio dataset`` and ``gap-benchmark`` on local Ray with 2 workers vs 1, and Ray's scheduling
overhead per task (issue #15).

Each figure starts its own local Ray instance (``num_cpus`` = the worker count) and times the job after Ray is up
(the start-up, ≈10 s here, is printed apart); the per-task overhead is the wall time of N no-op tasks through
:func:`proprio.tasks.run_tasks` (which also writes one result file per task) and through bare ``ray.remote``,
divided by N. Run with ``OPENBLAS_NUM_THREADS=1`` on an otherwise idle machine; prints ``uptime`` before and after.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
import time


def _noop(i: int) -> int:
    return i


def _with_ray(workers: int, fn):
    from proprio.tasks import init_ray
    import ray

    t0 = time.perf_counter()
    init_ray(num_cpus=workers)
    start = time.perf_counter() - t0
    try:
        return start, fn()
    finally:
        ray.shutdown()


def bench_dataset(workers: int, seeds: int, seconds: float) -> tuple[float, float]:
    from proprio.experiments.dataset import DatasetSpec, build_dataset

    spec = DatasetSpec(seeds=tuple(range(1, seeds + 1)), scaffolds=2, seconds=seconds, log_rate_hz=200.0)

    def job() -> float:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            build_dataset(spec, tmp, backend="ray", progress=False)
            return time.perf_counter() - t0
    return _with_ray(workers, job)


def bench_gap(workers: int, cases: list[str]) -> tuple[float, float]:
    from proprio.gap_benchmark.run import run_benchmark
    from proprio.gap_benchmark.cases import make_cases, select_cases

    chosen = select_cases(make_cases(quick=True), cases)

    def job() -> float:
        t0 = time.perf_counter()
        run_benchmark(chosen, backend="ray", progress=False)
        return time.perf_counter() - t0
    return _with_ray(workers, job)


def bench_overhead(n: int) -> tuple[float, float]:
    import ray

    from proprio.tasks import Task, run_tasks

    def job() -> tuple[float, float]:
        remote = ray.remote(_noop)
        ray.get([remote.remote(i) for i in range(50)])          # warm the workers
        t0 = time.perf_counter()
        ray.get([remote.remote(i) for i in range(n)])
        bare = (time.perf_counter() - t0) / n
        with tempfile.TemporaryDirectory() as tmp:
            tasks = [Task(f"noop{i}", _noop, {"i": i}, {"i": i}) for i in range(n)]
            t0 = time.perf_counter()
            run_tasks(tasks, tmp, backend="ray", progress=False)
            engine = (time.perf_counter() - t0) / n
        return bare, engine
    return _with_ray(2, job)[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=4, help="dataset: RFMA seeds (tasks), 2 scaffolds each (default 4)")
    ap.add_argument("--seconds", type=float, default=40.0, help="dataset: seconds simulated per seed (default 40)")
    ap.add_argument("--cases", nargs="+", default=["viscous_coulomb@1", "hysteresis@1", "null#0", "ripple@1"],
                    help="gap-benchmark: cases of the --quick list (default: 4)")
    ap.add_argument("--noop", type=int, default=500, help="no-op tasks for the overhead (default 500)")
    ap.add_argument("--skip", nargs="*", default=[], choices=["dataset", "gap", "overhead"], help="figures to skip")
    args = ap.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    if "dataset" not in args.skip:
        (s1, t1), (s2, t2) = bench_dataset(1, args.seeds, args.seconds), bench_dataset(2, args.seeds, args.seconds)
        print(f"dataset ({args.seeds} seeds × {args.seconds:g} s of twin): 1 worker {t1:.1f} s, 2 workers {t2:.1f} s "
              f"-> speed-up {t1 / t2:.2f}x  (Ray start-up {s1:.1f} / {s2:.1f} s, not included)")
    if "gap" not in args.skip:
        (s1, t1), (s2, t2) = bench_gap(1, args.cases), bench_gap(2, args.cases)
        print(f"gap-benchmark ({len(args.cases)} quick cases): 1 worker {t1:.1f} s, 2 workers {t2:.1f} s "
              f"-> speed-up {t1 / t2:.2f}x  (Ray start-up {s1:.1f} / {s2:.1f} s, not included)")
    if "overhead" not in args.skip:
        bare, engine = bench_overhead(args.noop)
        print(f"scheduling overhead per no-op task ({args.noop} tasks, 2 workers): bare ray.remote "
              f"{1e3 * bare:.2f} ms, run_tasks (+ result file) {1e3 * engine:.2f} ms")
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())


if __name__ == "__main__":
    main()
