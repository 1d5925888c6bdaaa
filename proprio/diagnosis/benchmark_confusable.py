"""The confusable-pairs family of the gap benchmark (issue #25), scored before and after the designed experiment.

Each case withholds one effect that another candidate can imitate on the benchmark's motions
(:data:`CONFUSABLE_PAIRS`: the truth and its usual impostor). The case's data are made as every benchmark case's
(:func:`proprio.diagnosis.benchmark_cases.generate_case_data`, offline or through the twin); the diagnosis chooses
among :data:`CONFUSABLE_CANDIDATES`. Scores:

* **before**: the first diagnosis names the truth as top-1, or reports the tie (the truth is in the tied set of the
  top-1 effect, :mod:`proprio.diagnosis.ambiguity`);
* **after**: the experiment of every tied set is designed (:mod:`proprio.diagnosis.discriminate`), recorded on the
  case's robot (the same effects and noise; offline: the effect library applied to the planned motion; twin: the
  case's twin), its two passes added to the training and held-out data, and the diagnosis run again: top-1 is the
  truth. A case whose first diagnosis has no tie is scored after as before (no experiment was needed).

Pre-sliding friction against lost motion is not in the family yet: the library has no pre-sliding effect.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from proprio.diagnosis.benchmark_cases import RATE_HZ, BenchmarkCase, generate_case_data, twin_case_config
from proprio.effects import EFFECTS

__all__ = ["CONFUSABLE_PAIRS", "CONFUSABLE_CANDIDATES", "VARIANTS", "ConfusableResult", "confusable_cases",
           "run_confusable_case", "summarise_confusable"]

CONFUSABLE_PAIRS = (("hysteresis", "viscous_coulomb", ""), ("hysteresis", "viscous_coulomb", "short"),
                    ("viscous_coulomb", "hysteresis", ""), ("lost_motion", "hysteresis", ""),
                    ("sensor_offset_gain", "rigid_body", ""), ("payload", "rigid_body", ""))
"""``(truth, impostor, variant)``: a variant sets parameters of the truth over the benchmark's draw
(:data:`VARIANTS`)."""

VARIANTS = {"short": {"hysteresis": {"saturation_travel": math.radians(0.5)}}}
"""``short``: a hysteresis that saturates within 0.5° — the "Coulomb step in disguise" of issue #25's real log (the
benchmark draws 4–8°). Offline only (the twin mode draws its own)."""

CONFUSABLE_CANDIDATES = ("viscous_coulomb", "hysteresis", "lost_motion", "sensor_offset_gain", "rigid_body", "payload")
"""The candidates the family's diagnoses choose among: every effect of the pairs (the library-wide choice is the main
benchmark's; this family scores the ties and their resolution)."""

_BASE = {"sensor_offset": "sensor_offset_gain", "sensor_gain": "sensor_offset_gain"}


@dataclass
class ConfusableResult:
    """One case: the first diagnosis' top-1 and tied set, the experiments (members, family, score), the top-1 after
    the experiment, and the seconds it took."""
    case: str
    truth: str
    top_before: str
    tied_before: list[str]
    experiments: list[dict[str, Any]] = field(default_factory=list)
    top_after: str = ""
    tied_after: list[str] = field(default_factory=list)
    seconds: float = 0.0
    error: str = ""

    @property
    def ok_before(self) -> bool:
        return self.top_before == self.truth or self.truth in self.tied_before

    @property
    def ok_after(self) -> bool:
        return self.top_after == self.truth


def confusable_cases(seed: int = 0, magnitudes: tuple[float, ...] = (1.0,), twin: bool = False,
                     duration_s: float = 20.0) -> list[BenchmarkCase]:
    """One case per :data:`CONFUSABLE_PAIRS` entry and magnitude, named ``confusable:<truth>[/<variant>]@<m>``
    (twin mode: the entries without a variant)."""
    rng = np.random.default_rng([seed, 25])
    prefix = "twin:confusable:" if twin else "confusable:"
    return [BenchmarkCase(f"{prefix}{truth}{'/' + var if var else ''}@{m:g}", (truth,), m,
                          int(rng.integers(1 << 30)), duration_s=duration_s, twin=twin)
            for truth, _, var in CONFUSABLE_PAIRS for m in magnitudes if not (twin and var)]


def _overrides(case: BenchmarkCase, n: int) -> dict[str, dict[str, Any]]:
    """The case's variant (``.../<variant>@m`` in its name) as parameter overrides for ``n`` joints."""
    head = case.name.rpartition("@")[0]
    var = head.rpartition("/")[2] if "/" in head else ""
    return {k: {p: np.full(n, v) for p, v in ps.items()} for k, ps in VARIANTS.get(var, {}).items()}


def _top(att) -> tuple[str, list[str]]:
    """Top-1 physical effect (sub-candidates as their library effect) and its tied set."""
    if not att.physical_steps:
        return "(none)", []
    first = att.physical_steps[0].name
    tied = next((a.members for a in att.ambiguity if a.effect == first), [first])
    return _BASE.get(first, first), [_BASE.get(k, k) for k in tied]


def _experiment_recording(case: BenchmarkCase, trajectory):
    """The case's robot run along ``trajectory``: offline the effect library on the planned motion, else the twin."""
    from proprio.systems.trajectories import sample_trajectory

    if case.twin:
        from proprio.diagrams.twin import simulate_twin
        return simulate_twin(twin_case_config(case, recording=2)[0], trajectory, progress=False)
    t, q, qd, qdd = sample_trajectory(trajectory, RATE_HZ)
    return generate_case_data(case, motions=[(t - t[0], q, qd, qdd, np.zeros(len(t)))],
                              overrides=_overrides(case, q.shape[1])).train[0]


def run_confusable_case(case: BenchmarkCase) -> ConfusableResult:
    """Diagnose the case, design and record the experiment of every tied set, diagnose again (module docstring)."""
    from proprio.diagnosis.data import SimModel
    from proprio.diagnosis.resolve import design_experiments, with_experiments
    from proprio.diagnosis.selection import attribute

    t0 = time.perf_counter()
    data = generate_case_data(case, overrides=None if case.twin else _overrides(case, 7))
    n = data.robot.n
    model = SimModel(data.robot, tuple(EFFECTS[k](n, **data.model_params[k]) for k in data.model_effects))
    truth = case.withheld[0]
    try:
        att = attribute(model, data.train, data.holdout, candidates=CONFUSABLE_CANDIDATES)
    except ValueError as exc:
        return ConfusableResult(case.name, truth, "", [], seconds=time.perf_counter() - t0, error=str(exc))
    top, tied = _top(att)
    res = ConfusableResult(case.name, truth, top, tied, top_after=top, tied_after=tied)
    designed = [d for d in design_experiments(model, att) if d.experiment is not None]
    res.experiments = [{"members": d.members, "family": d.experiment.family, "label": d.experiment.label,
                        "score": d.experiment.score, "decides": d.experiment.decides} for d in designed]
    runs = [d for d in designed if d.experiment.decides]
    if runs:
        recs = [_experiment_recording(case, d.experiment.trajectory) for d in runs]
        train, hold = with_experiments(data.train, data.holdout, recs, [d.experiment.split_s for d in runs])
        res.top_after, res.tied_after = _top(attribute(model, train, hold, candidates=CONFUSABLE_CANDIDATES))
    res.seconds = time.perf_counter() - t0
    return res


def summarise_confusable(results: list[ConfusableResult]) -> tuple[dict[str, Any], str]:
    """Share of cases whose first diagnosis names the truth or reports the tie, and top-1 after the experiment."""
    ok = [r for r in results if not r.error]
    before = float(np.mean([r.ok_before for r in ok])) if ok else float("nan")
    top1_before = float(np.mean([r.top_before == r.truth for r in ok])) if ok else float("nan")
    after = float(np.mean([r.ok_after for r in ok])) if ok else float("nan")
    lines = [f"{'case':32s} {'top-1 before':18s} {'tied before':36s} {'experiment':40s} top-1 after"]
    for r in results:
        exp = "; ".join(f"{e['family']} z={e['score']:.1f}" for e in r.experiments) or "—"
        lines.append(f"{r.case:32s} {r.top_before:18s} {'+'.join(r.tied_before):36s} {exp:40s} {r.top_after}"
                     + (f"  ERROR {r.error}" if r.error else ""))
    lines += ["", f"confusable pairs: {len(ok)} cases; first diagnosis right or tie reported {100 * before:.0f} % "
              f"(top-1 right {100 * top1_before:.0f} %); top-1 after one designed experiment {100 * after:.0f} %"]
    return {"cases": len(ok), "before_right_or_tie": before, "top1_before": top1_before, "top1_after": after}, \
        "\n".join(lines)
