"""The diagnosis at scale: 10 min of a 1 kHz robot-like twin log, decimated automatically (issue #22).

    .venv/bin/python benchmarks/bench_long_log.py [--minutes 10] [--compare-seconds 30] [--no-long] [--work DIR]

**Data.** The twin's friction-withheld case of the gap benchmark (:func:`proprio.gap_benchmark.case_data.
twin_case_config`: ``iiwa14_twin`` with its link friction, background torque and encoder noise) along long RFMA
trajectories, two recordings (training, held out) of ``minutes / 2`` each, logged like a robot: 1 kHz, host-stamp
jitter σ = 0.1 ms, 2 % of the samples followed by a burst of 1–7 lost ones, q and τ only — and 5 % repeated packets
(a logging host that writes the last packet again when no new one arrived: rows with the stamp and values of their
predecessor), merged where they enter by :func:`proprio.recording.merge_duplicate_stamps`, as the importer does. The
raw logs are cached under ``--work`` (``np.savez``, written atomically), so a rerun skips the simulation.

**Diagnosis.** :func:`proprio.diagnosis.diagnose` of the model without friction (``iiwa14_identified``'s rigid
body + the background torque and encoder noise) on the two recordings with the diagnosis' conditioning
(``DIAGNOSIS_CONDITIONING``: the decimation it chooses itself), timed in wall and CPU seconds of this process; it
prints samples/s and the ratio to real time. **Verdict check**: the named effects and the data-path findings, in
order, must be those of the diagnosis at full rate (``decimate: false``). The full-rate diagnosis of the whole log is
slow, so both rates are compared on the first ``--compare-seconds`` of each recording (a value at least the recording
length: the whole log at both rates; ``--no-long`` runs only that comparison), and the long log's verdict must be the
same too. Target: ≤ 3 min wall on 2 idle cores.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from proprio.gap_benchmark.case_data import twin_case_config
from proprio.gap_benchmark.recordings import ENCODER, NOISE_STD
from proprio.gap_benchmark.cases import BenchmarkCase
from proprio.recording import Recording, merge_duplicate_stamps, validate_recording

LOGGER = (("rate_hz", 1000.0), ("stamp_jitter_ms", 0.1), ("dropout_prob", 0.02), ("dropout_max_samples", 7))
REPEATED_PACKETS = 0.05
SECONDS_PER_SCAFFOLD = 15.0        # RFMA gives ≈19–21 s of motion per scaffold; a margin, the log is cut to length
TARGET_WALL_S = 180.0


def _case(seed: int) -> BenchmarkCase:
    return BenchmarkCase("long:viscous_coulomb", ("viscous_coulomb",), 1.0, seed, twin=True, logger=LOGGER)


def generate(work: Path, seconds: float, seed: int) -> list[Path]:
    """The raw logs (training, held out) of ``seconds`` [s] each under ``work``; simulated only when missing."""
    from proprio.diagrams.twin import simulate_twin
    from proprio.systems.rfma import RfmaError, generate_rfma, load_rfma_config

    work.mkdir(parents=True, exist_ok=True)
    case = _case(seed)
    paths = []
    for k, role in enumerate(("train", "holdout")):
        path = work / f"{role}_{seconds:g}s_seed{seed}.npz"
        paths.append(path)
        if path.exists():
            continue
        config = twin_case_config(case, recording=k)[0]
        rfma_seed = (seed + 7919 * k) % (1 << 31)
        for attempt in range(5):                      # RFMA may find no collision-free reach: next seed
            try:
                cfg = load_rfma_config(scaffolds=math.ceil(seconds / SECONDS_PER_SCAFFOLD) + 1, seed=rfma_seed)
                trajectory = generate_rfma(cfg, config.robot)[1].trajectory
                break
            except RfmaError:
                if attempt == 4:
                    raise
                rfma_seed = (rfma_seed + 104729) % (1 << 31)
        t0 = time.perf_counter()
        rec = simulate_twin(dataclasses.replace(config, seed=rfma_seed), trajectory, progress=False)
        if rec.duration < seconds:
            raise RuntimeError(f"{role}: the RFMA trajectory gave {rec.duration:.0f} s < {seconds:g} s; raise "
                               "SECONDS_PER_SCAFFOLD's margin")
        keep = rec.t - rec.t[0] <= seconds
        rng = np.random.default_rng([seed, k, 22])
        rows = np.repeat(np.flatnonzero(keep), 1 + (rng.random(int(keep.sum())) < REPEATED_PACKETS))
        fd, tmp = tempfile.mkstemp(dir=work, suffix=".npz")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, t=rec.t[rows], q=rec.q[rows], tau=rec.tau[rows],
                     session_time_s=float(rec.meta.get("session_time_s", 0.0)))
        os.replace(tmp, path)
        print(f"  simulated {role}: {seconds:g} s in {time.perf_counter() - t0:.0f} s wall -> {path}")
    return paths


def load(path: Path) -> Recording:
    """A cached raw log as a Recording, its repeated packets merged as the importer merges them."""
    with np.load(path, allow_pickle=False) as z:
        rec = Recording(t=z["t"], q=z["q"], tau=z["tau"],
                        meta={"source": f"bench_long_log:{path.name}", "session_time_s": float(z["session_time_s"])})
    return validate_recording(merge_duplicate_stamps(rec), source=str(path))


def model_of(seed: int):
    """The model under diagnosis: the twin's rigid body without friction + the background noise effects."""
    from proprio.diagnosis.data import SimModel
    from proprio.effects import EFFECTS

    robot = twin_case_config(_case(seed))[0].robot.without_friction()
    n = robot.n
    return SimModel(robot, (EFFECTS["torque_noise"](n, std=np.full(n, NOISE_STD)),
                            EFFECTS["encoder_noise"](n, **{k: np.full(n, v) for k, v in ENCODER.items()})))


def run(model, train: Recording, hold: Recording, decimate: bool, out: Path) -> dict:
    """One diagnosis, timed: its verdict ``(named, data path)``, wall and CPU seconds, the conditioning lines."""
    from proprio.diagnosis.data import DIAGNOSIS_CONDITIONING
    from proprio.diagnosis import diagnose

    cond = dataclasses.replace(DIAGNOSIS_CONDITIONING, decimate=decimate)
    w0, c0 = time.perf_counter(), time.process_time()
    d = diagnose(model, [train], [hold], out, conditioning=cond)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    att = d.attribution
    return {"named": tuple(att.selected), "data_path": tuple(att.processing_findings), "wall": wall, "cpu": cpu,
            "gains": {s.name: float(s.gain) for s in att.steps}, "conditioning": list(att.conditioning),
            "samples": train.n_samples + hold.n_samples, "seconds": train.duration + hold.duration}


def show(label: str, r: dict) -> None:
    print(f"{label}: {r['seconds']:.0f} s of log ({r['samples']} samples) in {r['wall']:.1f} s wall, "
          f"{r['cpu']:.1f} s CPU -> by wall {r['samples'] / r['wall'] / 1e3:.1f} k samples/s, "
          f"{r['seconds'] / r['wall']:.1f}x real time; by CPU {r['samples'] / r['cpu'] / 1e3:.1f} k samples/s, "
          f"{r['seconds'] / r['cpu']:.1f}x real time")
    gains = ", ".join(f"{k} {100 * v:.0f} %" for k, v in r["gains"].items())
    print(f"  named: {' > '.join(r['named']) or '(nothing)'}; data path: {', '.join(r['data_path']) or '-'}"
          f"{f' (held-out gains: {gains})' if gains else ''}")
    for line in r["conditioning"][:2]:
        print(f"  {line[:200]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="minutes of log in all, half held out (default 10)")
    ap.add_argument("--compare-seconds", type=float, default=30.0,
                    help="seconds of each recording diagnosed at both rates (0: no comparison; default 30)")
    ap.add_argument("--no-long", action="store_true", help="only the comparison at both rates (run it apart)")
    ap.add_argument("--seed", type=int, default=2211)
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "proprio_bench_long_log",
                    help="cache of the simulated logs and the reports")
    args = ap.parse_args()
    seconds = 30.0 * args.minutes
    print(f"load average at start {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    train, hold = (load(p) for p in generate(args.work, seconds, args.seed))
    model = model_of(args.seed)
    for name, rec in (("train", train), ("holdout", hold)):
        dup = rec.meta.get("duplicate_stamps", {})
        steps = np.diff(rec.t)
        print(f"{name}: {rec.duration:.0f} s, {rec.n_samples} samples, steps {1e3 * steps.min():.2f}–"
              f"{1e3 * steps.max():.2f} ms, {dup.get('stamps', 0)} repeated packets merged")
    ok, verdicts = True, []
    verdict = lambda r: (r["named"], r["data_path"])  # noqa: E731
    if not args.no_long:
        long = run(model, train, hold, True, args.work / "report_long")
        show(f"diagnosis, {2 * seconds / 60:g} min, automatic decimation", long)
        ok &= long["wall"] <= TARGET_WALL_S
        verdicts.append(verdict(long))
        print(f"wall {long['wall']:.1f} s {'<=' if ok else '>'} {TARGET_WALL_S:.0f} s")
    if args.compare_seconds > 0:
        n_cut = lambda r: int(np.searchsorted(r.t - r.t[0], args.compare_seconds, side="right"))  # noqa: E731
        seg = [r.slice(0, n_cut(r)) for r in (train, hold)]
        what = f"first {min(args.compare_seconds, seconds):g} s of each recording"
        dec = run(model, *seg, True, args.work / "report_segment")
        full = run(model, *seg, False, args.work / "report_full_rate")
        show(f"{what}, automatic decimation", dec)
        show(f"{what}, full rate (no decimation)", full)
        verdicts += [verdict(dec), verdict(full)]
    same = all(v == verdicts[0] for v in verdicts)
    ok &= same
    print(f"verdict {'the same' if same else 'DIFFERS'} in all {len(verdicts)} diagnoses: "
          + "; ".join(" > ".join(v[0]) or "(nothing)" for v in verdicts))
    print("all checks pass" if ok else "some checks fail")

if __name__ == "__main__":
    main()
