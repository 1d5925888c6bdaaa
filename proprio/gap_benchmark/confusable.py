"""The confusable-pairs family of the gap benchmark (issue #25), scored before and after the designed experiment.

Each case withholds one effect that another candidate can imitate (:data:`CONFUSABLE_PAIRS`: the truth, its
impostor and a variant of the truth's parameters), on recordings whose motion makes the pair confusable: a few
reaches of 6–14° per joint between rest poses at 8–20 % of the speed limits (9–15 s each, every joint reversing
up to 6 times, always after many degrees of travel), meant to make a Dahl loop that saturates within a degree look
like a Coulomb step and to show a load law only a few load levels (measured, README "Confusable effects": on these
slow reaches the first diagnosis still separates every pair; the ``fast`` variant's reaches leave hysteresis and
Coulomb tied). The diagnosis chooses among :data:`CONFUSABLE_CANDIDATES`.

**Data.** Twin mode (``twin=True``, ``proprio gap-benchmark --confusable --twin``, the family's mode): every
recording is :func:`proprio.diagrams.twin.simulate_twin` of the shipped ``iiwa14_twin`` (robot ``iiwa14_identified``,
its controller and hidden motor-side drive) with its joint effects replaced by the withheld one and the background
torque and encoder noise, logged at :data:`RATE_HZ` (q and τ only, jittered stamps and lost samples); a payload by
``TwinConfig.with_payload``, a rigid-body error as the twin's robot with perturbed link inertials; pre-sliding
friction acts in the twin's drive (:class:`~proprio.systems.joint_drive.JointDrive`). The designed experiment is
run on the same twin. Offline (default, cheap): the same motions and effects, the effect library applied to the
planned motion (link-side friction, then the sensor effects on the resulting τ_J) — no Drake simulation.
The model is ``iiwa14_identified`` without friction + the background noise.

**Scores** (:func:`summarise_confusable`):

* **before**: the first diagnosis names the truth as top-1, or reports the tie (the truth is in the tied set of the
  top-1 effect, :mod:`proprio.diagnosis.selection.ambiguity`);
* **after**: the experiment of every tied set is designed (:mod:`proprio.diagnosis.discriminate`), recorded on the
  case's robot, its two passes added to the training and held-out data, and the diagnosis run again: top-1 is the
  truth. A case whose first diagnosis has no tie is scored after as before (no experiment was needed); a tied set no
  motion of the family separates is said so (``experiments[..]["decides"]`` false) and not recorded.

The truth's expected name (:func:`proprio.gap_benchmark.cases.expected_name`): on a link-side torque sensor
(the iiwa's) the drive's pre-sliding friction is, in τ_J, the Dahl law the diagnosis offers as the gauge's ``hysteresis``
(:data:`proprio.diagnosis.candidates.drive.DRIVE_ONLY`), so that is the right name for it; a load-dependent friction
(a direction-flipping level that grows with the transmitted torque) is the Dahl law with a ``load_gain``: the
library's ``hysteresis`` with a short travel. (The library's own ``load_friction`` — ``(F_c0 + k|τ_J|) sgn_s(q̇)``,
:mod:`proprio.friction_law` — is not among this family's candidates: the pair tests the loop's load gain against a
sensor gain error; the load-dependent friction cases are in the offline, twin and drive families.)
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from proprio.gap_benchmark.case_data import _perturbed
from proprio.gap_benchmark.recordings import ENCODER, NOISE_STD, CaseData
from proprio.gap_benchmark.cases import BenchmarkCase, _draw, expected_name
from proprio.effects import EFFECTS

__all__ = ["CONFUSABLE_PAIRS", "CONFUSABLE_CANDIDATES", "VARIANTS", "RATE_HZ", "ConfusableResult",
           "confusable_cases", "confusable_params", "confusable_motion", "confusable_data", "run_confusable_case",
           "summarise_confusable"]

NOISY = 4.0                      # the noisy variant's torque-noise factor
RATE_HZ = 100.0                  # Hz, the family's log rate (the motions are slow: ≤ 25 % of the speed limits)
LEGS = 7                         # reaches per recording (each joint reverses LEGS − 1 times)
LEG_DEG = (6.0, 14.0)            # ° per joint and reach
SPEED = (0.08, 0.20)             # fraction of the velocity limits per reach
FAST = (0.4, 0.7)                # ... in the fast variant

CONFUSABLE_PAIRS = (("hysteresis", "viscous_coulomb", "short"), ("viscous_coulomb", "hysteresis", ""),
                    ("presliding", "lost_motion", ""), ("lost_motion", "hysteresis", ""),
                    ("hysteresis", "sensor_offset_gain", "load"), ("sensor_offset_gain", "hysteresis", "gain"),
                    ("payload", "rigid_body", ""), ("rigid_body", "payload", ""),
                    ("hysteresis", "viscous_coulomb", "short-noisy"), ("viscous_coulomb", "hysteresis", "noisy"),
                    ("hysteresis", "viscous_coulomb", "short-fast"))
"""``(truth, impostor, variant)``: hysteresis vs Coulomb (both ways), pre-sliding friction vs lost motion (both
ways), load-dependent friction vs a sensor gain error (both ways), payload vs rigid body (both ways), and hysteresis
vs Coulomb again in a noisier sensor (``noisy``) and on fast reaches (``fast``). A variant joins its parts with
``-``."""

VARIANTS = {"short": "a hysteresis that saturates within 0.2–0.4° (a Coulomb step in disguise: issue #25's real log)",
            "load": "load-dependent friction: a direction-flipping level of 0.05–0.15 N·m + 2–5 % of |τ_J|, "
                    "turning over within 0.3–0.6° (the Dahl law with a load gain)",
            "gain": "a sensor gain error of 1–3 % alone (no offset)",
            "noisy": f"a torque sensor {NOISY:g}× noisier ({NOISY * NOISE_STD:g} N·m; data and model): the shape of "
                     "a reversal drowns, the level does not",
            "fast": f"reaches at {FAST[0]:g}–{FAST[1]:g} of the speed limits: a reversal's travel-dependent turn-over "
                    "lasts a few samples"}
"""The variants of the truth's parameters over the benchmark's draw (:func:`confusable_params`)."""

CONFUSABLE_CANDIDATES = ("viscous_coulomb", "hysteresis", "lost_motion", "sensor_offset_gain", "rigid_body", "payload")
"""The candidates the family's diagnoses choose among: every effect of the pairs (pre-sliding as the Dahl law,
``hysteresis``, on a link-side sensor)."""

_BASE = {"sensor_offset": "sensor_offset_gain", "sensor_gain": "sensor_offset_gain"}


@dataclass
class ConfusableResult:
    """One case: the first diagnosis' top-1 and tied set, the experiments (members, family, score, whether it
    decides), the top-1 after the experiment, and the seconds it took. ``truth``: the name the diagnosis should give
    the withheld effect (:func:`~proprio.gap_benchmark.cases.expected_name`)."""
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
                     duration_s: float = 12.0) -> list[BenchmarkCase]:
    """One case per :data:`CONFUSABLE_PAIRS` entry and magnitude, named
    ``[twin:]confusable:<truth>[/<variant>]@<m>`` (``duration_s``: nominal, the motion sets it)."""
    rng = np.random.default_rng([seed, 25])
    prefix = "twin:confusable:" if twin else "confusable:"
    return [BenchmarkCase(f"{prefix}{truth}{'/' + var if var else ''}@{m:g}", (truth,), m,
                          int(rng.integers(1 << 30)), duration_s=duration_s, twin=twin)
            for truth, _, var in CONFUSABLE_PAIRS for m in magnitudes]


def _variant(case: BenchmarkCase) -> set[str]:
    """The parts of the case's variant (``.../short-noisy@m`` → {short, noisy})."""
    head = case.name.rpartition("@")[0]
    return set(head.rpartition("/")[2].split("-")) if "/" in head else set()


def _noise(case: BenchmarkCase) -> float:
    """The case's torque-sensor noise [N·m] (data and model)."""
    return NOISE_STD * (NOISY if "noisy" in _variant(case) else 1.0)


def confusable_params(case: BenchmarkCase, n: int) -> dict[str, Any]:
    """The withheld effect's parameters for ``n`` joints: the benchmark's draw
    (:func:`proprio.gap_benchmark.cases._draw`) at the case's magnitude, changed by its variant (:data:`VARIANTS`);
    pre-sliding: a level of 0.15–0.4 N·m turning over within 0.5–1.5° (at most
    :data:`proprio.effects.dahl.MAX_PRESLIDING_TRAVEL`)."""
    rng = np.random.default_rng(case.seed)
    kind, m, var = case.withheld[0], case.magnitude, _variant(case)
    u = lambda a, b: rng.uniform(a, b, n)  # noqa: E731
    if kind == "presliding":
        return {"level": m * u(0.15, 0.4), "presliding_travel": np.radians(u(0.5, 1.5))}
    if "short" in var:
        return {"saturation": m * u(0.2, 0.5), "saturation_travel": np.radians(u(0.2, 0.4))}
    if "load" in var:
        return {"saturation": m * u(0.05, 0.15), "load_gain": np.minimum(m * u(0.02, 0.05), 0.1),
                "saturation_travel": np.radians(u(0.3, 0.6))}
    if "gain" in var:
        return {"offset": np.zeros(n), "gain": m * u(0.01, 0.03) * rng.choice([-1.0, 1.0], n)}
    if kind == "viscous_coulomb":          # a Coulomb level that shows on every joint (the draw's 0.03 does not)
        return {"viscous": m * u(0.10, 0.37), "coulomb": m * u(0.10, 0.32)}
    return _draw(kind, n, m, rng)


def _robot():
    from proprio.diagrams.twin import load_twin_config
    return load_twin_config("iiwa14_twin").robot.without_friction()


def confusable_motion(robot, seed: int, speed: tuple[float, float] = SPEED):
    """One recording's motion (module docstring): :data:`LEGS` rest-to-rest reaches of :data:`LEG_DEG` per joint
    (random signs) around a drawn pose at ``speed`` (fractions of the velocity limits), back to the pose; the first
    collision-free draw of up to 20. Returns the Drake trajectory."""
    from proprio.collision import CollisionChecker
    from proprio.systems.trajectories import Phase, sample_trajectory, time_parameterize

    checker = CollisionChecker(robot)
    rng = np.random.default_rng([seed, 2025])
    mid, half = 0.5 * (robot.lower + robot.upper), 0.5 * (robot.upper - robot.lower)
    for _ in range(20):
        q0 = mid + rng.uniform(-0.3, 0.3, robot.n) * half
        pts = [q0] + [q0 + np.radians(rng.uniform(*LEG_DEG, robot.n)) * rng.choice([-1.0, 1.0], robot.n)
                      for _ in range(LEGS - 1)] + [q0]
        phases = []
        for a, b in zip(pts[:-1], pts[1:]):
            vf = float(rng.uniform(*speed))
            phases.append(Phase(np.stack([a, b]), vf, min(1.0, 2 * vf), "reach"))
        traj = time_parameterize(phases, robot).trajectory
        if not checker.any_collision(sample_trajectory(traj, 10.0)[1]):
            return traj
    raise RuntimeError(f"confusable motion: no collision-free draw for seed {seed}")


def _twin_config(case: BenchmarkCase, seed: int):
    """The case's twin (module docstring) with its noise seeded by ``seed``."""
    from proprio.diagrams.twin import load_twin_config
    from proprio.payload import Payload

    config = load_twin_config("iiwa14_twin").with_payload(None).with_logger(rate_hz=RATE_HZ)
    n = config.robot.n
    kind, p = case.withheld[0], confusable_params(case, n)
    effects = [EFFECTS[kind](n, **p)] if kind in EFFECTS else []
    effects += [EFFECTS["torque_noise"](n, std=np.full(n, _noise(case))),
                EFFECTS["encoder_noise"](n, **{k: np.full(n, v) for k, v in ENCODER.items()})]
    config = replace(config.with_effects(effects), seed=seed)
    if kind == "rigid_body":
        config = replace(config, robot=_perturbed(config.robot, p))
    if kind == "payload":
        config = config.with_payload(Payload(p["mass"], tuple(p["com"])))
    return config


def _offline(case: BenchmarkCase, robot, traj, seed: int):
    """The recording of ``traj`` made offline: the effect library on the planned motion (module docstring)."""
    from proprio.dynamics import inverse_dynamics
    from proprio.payload import Payload, attach_payload
    from proprio.recording import Recording
    from proprio.signals import MotionSignals
    from proprio.systems.trajectories import sample_trajectory

    n = robot.n
    kind, p = case.withheld[0], confusable_params(case, n)
    data_robot = _perturbed(robot, p) if kind == "rigid_body" else robot
    if kind == "payload":
        data_robot = attach_payload(data_robot, Payload(p["mass"], tuple(p["com"])))
    t, q, qd, qdd = sample_trajectory(traj, RATE_HZ)
    s = MotionSignals(t, q, qd, qdd)
    tau = inverse_dynamics(data_robot, q, qd, qdd)
    eff = EFFECTS[kind](n, **p) if kind in EFFECTS else None
    if eff is not None and eff.place == "link":
        tau = tau + eff.torque(s)
    meas = tau + (eff.torque(s.with_tau(tau)) if eff is not None and eff.place == "sensor" else 0.0)
    rng = np.random.default_rng(seed)
    meas = meas + rng.normal(0.0, _noise(case), meas.shape)
    q_rec = EFFECTS["encoder_noise"](n, **{k: np.full(n, v) for k, v in ENCODER.items()}).measure(q, rng)
    return Recording(t=t, q=q_rec, tau=meas, meta={"robot": robot.name, "rate_hz": RATE_HZ,
                                                    "source": "gap-benchmark confusable (offline)"})


def _record(case: BenchmarkCase, robot, traj, k: int):
    """The case's robot run along ``traj`` as its recording ``k`` (own noise seed): the twin or offline."""
    seed = (case.seed + 7919 * k) % (1 << 31)
    if case.twin:
        from proprio.diagrams.twin import simulate_twin
        from proprio.recording import Recording
        rec = simulate_twin(_twin_config(case, seed), traj, progress=False)
        return Recording(t=rec.t, q=rec.q, tau=rec.tau, truth=rec.truth,
                         meta={**rec.meta, "source": "gap-benchmark confusable (twin)"})
    return _offline(case, robot, traj, seed)


def confusable_data(case: BenchmarkCase) -> CaseData:
    """The case's 2 training and 1 held-out recordings (module docstring) and the model's effects (background torque
    and encoder noise)."""
    robot = _robot()
    n = robot.n
    speed = FAST if "fast" in _variant(case) else SPEED
    recs = [_record(case, robot, confusable_motion(robot, case.seed + 7919 * k, speed), k) for k in range(3)]
    params = {"torque_noise": {"std": np.full(n, _noise(case))},
              "encoder_noise": {k: np.full(n, v) for k, v in ENCODER.items()}}
    return CaseData(robot, ("torque_noise", "encoder_noise"), params, recs[:2], recs[2:])


def _top(att) -> tuple[str, list[str]]:
    """Top-1 physical effect (sub-candidates as their library effect) and its tied set."""
    if not att.physical_steps:
        return "(none)", []
    first = att.physical_steps[0].name
    tied = next((a.members for a in att.ambiguity if a.effect == first), [first])
    return _BASE.get(first, first), [_BASE.get(k, k) for k in tied]


def run_confusable_case(case: BenchmarkCase) -> ConfusableResult:
    """Diagnose the case, design the experiment of every tied set, record the deciding ones on the case's robot,
    diagnose again (module docstring)."""
    from proprio.diagnosis.data import SimModel
    from proprio.diagnosis.resolve import design_experiments, with_experiments
    from proprio.diagnosis.selection.forward import attribute

    t0 = time.perf_counter()
    data = confusable_data(case)
    n = data.robot.n
    model = SimModel(data.robot, tuple(EFFECTS[k](n, **data.model_params[k]) for k in data.model_effects))
    truth = expected_name(case)
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
        recs = [_record(case, data.robot, d.experiment.trajectory, 3 + k) for k, d in enumerate(runs)]
        train, hold = with_experiments(data.train, data.holdout, recs, [d.experiment.split_s for d in runs])
        res.top_after, res.tied_after = _top(attribute(model, train, hold, candidates=CONFUSABLE_CANDIDATES))
    res.seconds = time.perf_counter() - t0
    return res


def summarise_confusable(results: list[ConfusableResult]) -> tuple[dict[str, Any], str]:
    """Share of cases whose first diagnosis names the truth or reports the tie, top-1 before, top-1 after the
    experiment, and how many cases had a tie and how many ties an experiment decided."""
    ok = [r for r in results if not r.error]
    mean = (lambda xs: float(np.mean(xs)) if ok else float("nan"))  # noqa: E731
    before, top1_before, after = (mean([r.ok_before for r in ok]), mean([r.top_before == r.truth for r in ok]),
                                  mean([r.ok_after for r in ok]))
    lines = [f"{'case':40s} {'truth':18s} {'top-1 before':18s} {'tied before':34s} {'experiment':38s} top-1 after"]
    for r in results:
        exp = "; ".join(f"{e['family']} z={e['score']:.1f}" + ("" if e["decides"] else " (does not decide)")
                        for e in r.experiments) or "—"
        lines.append(f"{r.case:40s} {r.truth:18s} {r.top_before:18s} {'+'.join(r.tied_before):34s} {exp:38s} "
                     f"{r.top_after}" + (f"  ERROR {r.error}" if r.error else ""))
    n_tied = sum(len(r.tied_before) > 1 for r in ok)
    n_run = sum(any(e["decides"] for e in r.experiments) for r in ok)
    lines += ["", f"confusable pairs: {len(ok)} cases; first diagnosis right or tie reported {100 * before:.0f} % "
              f"(top-1 right {100 * top1_before:.0f} %; {n_tied} with a tie, {n_run} with a deciding experiment); "
              f"top-1 after one designed experiment {100 * after:.0f} %"]
    return {"cases": len(ok), "before_right_or_tie": before, "top1_before": top1_before, "top1_after": after,
            "with_tie": n_tied, "with_experiment": n_run}, "\n".join(lines)
