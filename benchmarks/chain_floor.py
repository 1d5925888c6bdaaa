"""The floor of Tables 5.3 and 5.4 on measured channels: the twin's own exact model through the hybrid's signal chain.

    .venv/bin/python benchmarks/chain_floor.py --model best.pt [--table53 REC.npz ...] [--seconds 30]
        [--seeds 7 ...] [--without EFFECT ...]

A hybrid sees only what the robot logs: q and τ at jittered stamps, conditioned by the one path it was trained with
(zero-phase low-pass of q at ``cutoff_hz``, q̇ and q̈ from it, τ low-passed at ``tau_filter_hz``, the model rate).
``noise_calibration.py --table53`` bounds what the sensor's noise and ripple leave in the target; this script asks
what the rest of the chain leaves. The *exact* model of the twin — its robot, friction and every sensor law with the
parameters it simulated (``Recording.meta``, read here for scoring only; the link side by
:class:`~proprio.diagnosis.data.SimModel`, the sensor by the twin's :class:`~proprio.effects.sensor_chain.TorqueSensor`)
— is evaluated on the same conditioned signals as the hybrid and scored against the same targets. It is a
reference, not a bound: a learned model may do better where the exact laws commit to one reading of an ambiguous
turn and a network can hedge.

Printed, side by side with the hybrid on the same samples:

* ``--table53 REC ...`` (torque, Table 5.3): MSE per joint [N·m²] of the exact model and of the hybrid (streaming,
  state carried over the recording) against the training target, over every logged sample away from the filters'
  edges; and the exact model once more with its sensor laws given the *true* q and q̇ (the reversal state the
  measured channels cannot resolve at a slow turn), everything else measured.
* Table 5.4 (force): the validation runs of :func:`~proprio.experiments.payload.payload_experiment` (``--seconds``
  of RFMA each, one per ``--seeds``, 0 g and 1 kg at the flange, force-only Jacobian observer): RMSE per axis [N] of
  the hybrid (the estimation diagram) and of the exact model (:func:`estimate_rows`, the same observer's vectorised
  law) over the table's samples, the tared 1 kg run's mean error and per sample its share within 0.5 N on all axes
  (tare: the 0 g run's mean error); with several seeds, also every run's samples pooled. ``--without EFFECT`` removes twin
  effects from the runs (the hybrid, trained with them, is then no reference; the exact model is the twin's).
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from proprio.description import robot_from_dict
from proprio.diagnosis.data import NOISE_EFFECTS, SimModel
from proprio.diagrams.estimation import DEFAULT_GAIN, estimate_rows, load_torque_model, split_estimate
from proprio.diagrams.hybrid_torque_model import HybridTorqueModel
from proprio.diagrams.twin import TwinConfig, load_twin_config
from proprio.dynamics import inverse_dynamics
from proprio.effects.schema import make_effects
from proprio.experiments.payload import payload_experiment
from proprio.recording import Recording, load_recording
from proprio.signals import MotionSignals
from proprio.systems.observers import WrenchMapping
from proprio.effects.sensor_chain import TorqueSensor

TOLERANCE_N = 0.5          # Table 5.4's per-sample criterion for the tared 1 kg [N]


def exact_model(rec: Recording) -> SimModel:
    """The model the twin simulated ``rec`` with: its robot and its deterministic effects at their true parameters
    (the twin's link friction is its ``viscous_coulomb`` effect, not the description's friction block)."""
    robot = robot_from_dict(rec.meta["robot_description"]).without_friction()
    effects = [e for e in make_effects(rec.meta["effects"], robot.n) if e.name not in NOISE_EFFECTS]
    return SimModel(robot, tuple(effects))


def exact_torque(model: SimModel, s: MotionSignals, s_sensor: MotionSignals | None = None) -> np.ndarray:
    """τ_J [N·m] the exact model predicts on the conditioned motion ``s``: the link-side torque of ``model`` (rigid
    body + link effects), read through the twin's own sensor (:class:`TorqueSensor`: the gauge effects, then the gain
    on what the gauge sees, as the twin applies them); with ``s_sensor`` the sensor laws read that motion (the true
    one) instead, the link-side torque still from ``s``."""
    link = SimModel(model.robot, tuple(e for e in model.effects if e.place != "sensor")).predict(s)
    sensor = TorqueSensor([e for e in model.effects if e.place == "sensor"], model.robot.n)
    return sensor.measure(s if s_sensor is None else s_sensor, link)[0]


class ExactTorqueModel:
    """:func:`exact_model` as a :class:`~proprio.diagrams.torque_model.TorqueModel` for :func:`estimate_rows`: its
    ``tau_int`` is the exact τ_J minus the rigid body over one contiguous sequence at step ``time_step`` [s]."""

    def __init__(self, model: SimModel, time_step: float):
        self.model, self.time_step, self.description, self.name = model, time_step, model.robot, "exact twin model"

    def tau_int(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        s = MotionSignals(np.arange(q.shape[0]) * self.time_step, q, qd, qdd)
        return exact_torque(self.model, s) - inverse_dynamics(self.description, q, qd, qdd)


def _true_motion(rec: Recording, at_rate: Recording, sig: dict[str, np.ndarray]) -> MotionSignals:
    """The twin's true q, q̇ (``truth__*``) at the conditioned samples' stamps."""
    def at(x: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(at_rate.t, rec.t, x[:, j]) for j in range(x.shape[1])], axis=1)
    return MotionSignals(sig["t"], at(rec.truth["q_true"]), at(rec.truth["qd"]), sig["qdd"])


def table53(hyb: HybridTorqueModel, path: Path) -> dict[str, np.ndarray]:
    """Per-joint MSE [N·m²] against the training target of the exact model, the exact model with true reversal
    state, and the hybrid (streaming), over the recording's logged samples away from the filters' edges."""
    rec = load_recording(path)
    at_rate, sig = hyb.signals(rec)
    q, qd, qdd, target = sig["q"], sig["qd"], sig["qdd"], sig["tau"]
    t = sig["t"]
    keep = ~sig["gap"] & (t >= sig["edge_s"]) & (t <= t[-1] - sig["edge_s"])
    model = exact_model(rec)
    s = MotionSignals(t, q, qd, qdd)
    pred = {"exact model": exact_torque(model, s),
            "exact, true reversal state": exact_torque(model, s, _true_motion(rec, at_rate, sig)),
            "hybrid (streaming)": inverse_dynamics(hyb.description, q, qd, qdd) + hyb.tau_int(q, qd, qdd)}
    return {k: np.mean((p[keep] - target[keep]) ** 2, axis=0) for k, p in pred.items()}


def table54(hyb: HybridTorqueModel, out: Path, seconds: float, seed: int, twin: TwinConfig,
            masses: tuple[float, ...] = (0.0, 1.0)) -> dict[str, dict[float, np.ndarray]]:
    """Force errors ``{model: {mass [kg]: [N, 3] errors [N] over the table's samples}}`` of the hybrid and the exact
    model on the validation run simulated by ``twin`` with each payload mass."""
    mapping = WrenchMapping(force_only=True)
    pe = payload_experiment(hyb, out, seconds=seconds, masses=masses, seed=seed, mapping=mapping, twin_config=twin,
                            save_recordings=True)
    errors: dict[str, dict[float, np.ndarray]] = {"hybrid (diagram)": {}, "exact model": {}}
    for mass in masses:
        res = pe.results[mass]
        rec = load_recording(out / f"twin_{int(round(mass * 1000))}g.npz")
        _, sig = hyb.signals(rec)
        exact = ExactTorqueModel(exact_model(rec), sig["time_step"])
        w = split_estimate(estimate_rows(exact, sig, DEFAULT_GAIN, mapping), exact.description.n)["jacobian.wrench"]
        if w.shape[0] != res.t.shape[0]:
            raise RuntimeError(f"{mass} kg: {w.shape[0]} exact-model rows against {res.t.shape[0]} diagram rows")
        ok = res.valid()
        errors["hybrid (diagram)"][mass] = res.wrench["jacobian"][ok, :3] - res.f_true[ok, :3]
        errors["exact model"][mass] = w[ok, :3] - res.f_true[ok, :3]
    return errors


def _row(label: str, values: np.ndarray, fmt: str = "{:8.4f}") -> str:
    return f"{label:28s}" + "".join(fmt.format(v) for v in values)


def _force_line(label: str, zero: np.ndarray, one: np.ndarray, tared: np.ndarray) -> str:
    """RMSE at 0 g and 1 kg, the tared 1 kg's mean error and the share of its samples within ``TOLERANCE_N`` on all
    axes."""
    within = np.all(np.abs(tared) <= TOLERANCE_N, axis=1).mean()
    rms = [np.round(np.sqrt(np.mean(e ** 2, axis=0)), 3) for e in (zero, one)]
    return (f"{label:28s} 0 g {rms[0]}   1 kg {rms[1]}   tared 1 kg: mean error {np.round(tared.mean(axis=0), 3)}, "
            f"within {TOLERANCE_N} N on all axes {100 * within:.1f} % of samples")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, required=True, help="a hybrid model .pt trained on the twin")
    ap.add_argument("--table53", nargs="*", type=Path, default=[], metavar="REC",
                    help="twin recordings to score in torque (e.g. the check run)")
    ap.add_argument("--seconds", type=float, default=30.0, help="duration of each Table 5.4 validation run [s]")
    ap.add_argument("--seeds", nargs="+", type=int, default=[7], metavar="SEED",
                    help="seeds of Table 5.4's runs (7: payload-experiment's default); several runs are also pooled")
    ap.add_argument("--twin-config", default="iiwa14_twin",
                    help="the twin that simulates Table 5.4's runs (name or YAML)")
    ap.add_argument("--without", nargs="*", default=[], metavar="EFFECT",
                    help="simulate Table 5.4's runs with these twin effects removed (e.g. lost_motion): what each "
                         "costs")
    args = ap.parse_args()
    hyb = load_torque_model(args.model)
    if not isinstance(hyb, HybridTorqueModel):
        raise SystemExit(f"--model {args.model}: not a hybrid model (.pt written by `proprio train`)")
    twin = load_twin_config(args.twin_config)
    unknown = sorted(set(args.without) - {e.name for e in twin.effects})
    if unknown:
        raise SystemExit(f"--without: {unknown} not among {args.twin_config}'s effects "
                         f"{[e.name for e in twin.effects]}")
    twin = twin.with_effects([e for e in twin.effects if e.name not in args.without])
    for path in args.table53:
        mse = table53(hyb, path)
        n = len(next(iter(mse.values())))
        print(f"\nTable 5.3 on {path.name}: MSE against the training target [N·m²]")
        print(f"{'':28s}" + "".join(f"{'J' + str(j + 1):>10s}" for j in range(n)) + f"{'avg':>10s}")
        for k, v in mse.items():        # 6 decimals: a model at the floor is ~1e-4 N·m² here
            print(_row(k, np.append(v, v.mean()), "{:10.6f}"))
    without = f", without {', '.join(args.without)}" if args.without else ""
    print(f"\nTable 5.4 ({args.seconds:g} s RFMA per run, {args.twin_config}{without}, force-only Jacobian observer): "
          "RMSE [x y z] N")
    pooled: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as tmp:
            errors = table54(hyb, Path(tmp), args.seconds, seed, twin)
        for k, e in errors.items():
            run = (e[0.0], e[1.0], e[1.0] - e[0.0].mean(axis=0))       # tare: the 0 g run's mean error
            pooled.setdefault(k, []).append(run)
            print(_force_line(f"seed {seed}, {k}", *run))
    if len(args.seeds) > 1:
        for k, runs in pooled.items():
            print(_force_line(f"{len(runs)} runs, {k}", *(np.concatenate(x) for x in zip(*runs))))


if __name__ == "__main__":
    main()
