"""The automatic cutoff against the encoder's noise level: does the conditioning make the diagnosis' "before" gap?

    .venv/bin/python benchmarks/bench_noisy_cutoff.py [--levels 1e-4 2e-5 default] [--rates 1000 200 100]

For each encoder level (white noise σ [rad], no quantisation; ``default``: the benchmark's shipped 0.0005° + 0.0001°
quantisation) and log rate, the twin case ``twin:viscous_coulomb@1`` (seed 4242, 0.1 ms stamp jitter and the logger's
lost samples) is diagnosed with its friction withheld from a model that states no encoder noise (issue 39). Printed
per run: the auto cutoffs over the recordings and joints [Hz], how many recordings the time base put on the
controller's clock, the estimated σ_q range [µrad], the first step (and its ties), the data-path steps taken first,
the held-out gap before any step and the gap of the same model on the twin's exact motion (truth channels, inner 90 %:
what a perfect data path would leave) [N·m RMS over joints], the final gap, the data-path candidates' held-out gains
and the seconds taken.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from proprio.conditioning import condition
from proprio.diagnosis.data import DIAGNOSIS_CONDITIONING, SimModel
from proprio.diagnosis.selection.forward import attribute
from proprio.effects import EFFECTS
from proprio.gap_benchmark import case_data
from proprio.gap_benchmark.case_data import generate_twin_case_data
from proprio.gap_benchmark.cases import BenchmarkCase
from proprio.signals import MotionSignals


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def run(level: str, rate: float) -> str:
    """One line for the encoder ``level`` (σ [rad] or ``default``) and log ``rate`` [Hz]."""
    t0 = time.perf_counter()
    shipped = dict(case_data.ENCODER)
    if level != "default":
        case_data.ENCODER.update(std=float(level), resolution=0.0)
    try:
        case = BenchmarkCase(f"twin:viscous_coulomb@1/{rate:g}Hz", ("viscous_coulomb",), 1.0, 4242, twin=True,
                             logger=(("rate_hz", rate), ("stamp_jitter_ms", 0.1)))
        data = generate_twin_case_data(case)
    finally:
        case_data.ENCODER.update(shipped)
    recs = list(data.train) + list(data.holdout)
    cs = [condition(r, DIAGNOSIS_CONDITIONING) for r in recs]
    cut = np.concatenate([c.cutoff_hz for c in cs])
    sq = 1e6 * np.concatenate([c.sigma_q for c in cs])
    clock = sum(any("regular clock" in note for note in c.notes) for c in cs)
    n = data.robot.n
    model = SimModel(data.robot, tuple(EFFECTS[k](n, **data.model_params[k]) for k in data.model_effects
                                       if k != "encoder_noise"))
    att = attribute(model, data.train, data.holdout)
    exact = []
    for r in data.holdout:
        e = r.tau - model.predict(MotionSignals(r.t, r.truth["q_true"], r.truth["qd"], r.truth["qdd"], r.tau))
        exact.append(e[len(e) // 20:-(len(e) // 20)])
    first = f"{att.steps[0].name}{' (tied ' + ', '.join(att.steps[0].tied) + ')' if att.steps[0].tied else ''}" \
        if att.steps else "(nothing)"
    final = _rms(att.steps[-1].rmse_after) if att.steps else _rms(att.rmse_before)
    proc = ", ".join(f"{r['name']} {100 * r['gain']:.1f} %" for r in att.ranking if r["processing"])
    return (f"{level:>8} {rate:6g} Hz | cutoff {cut.min():5.1f}–{cut.max():5.1f} Hz, clock {clock}/{len(cs)}, "
            f"σ_q {sq.min():.1f}–{sq.max():.1f} µrad | first {first}, data path first "
            f"{[s.name for s in att.data_path] or 'none'} | gap {_rms(att.rmse_before):.3f} (exact motion "
            f"{_rms(np.concatenate(exact)):.3f}), final {final:.3f} N·m | data-path candidates: {proc} | "
            f"{time.perf_counter() - t0:.0f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", nargs="+", default=["1e-4", "2e-5", "default"],
                    help="encoder white noise σ [rad] or 'default' (default: 1e-4 2e-5 default)")
    ap.add_argument("--rates", nargs="+", type=float, default=[1000.0, 200.0, 100.0],
                    help="log rates [Hz] (default: 1000 200 100)")
    args = ap.parse_args()
    for level in args.levels:
        for rate in args.rates:
            print(run(level, rate), flush=True)


if __name__ == "__main__":
    main()
