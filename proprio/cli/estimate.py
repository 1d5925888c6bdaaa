"""``proprio estimate`` (wrench estimates over a Recording) and ``proprio payload-experiment`` (thesis §5, Table 5.4).

Both are thin wrappers: :func:`proprio.diagrams.estimation.estimate_wrench` and
:func:`proprio.experiments.payload.payload_experiment` do the work.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from proprio.cli import check_output, check_recording_robot, nonnegative, nonnegative_int, positive
from proprio.cli.flags import add_cutoff_hz, add_list, add_twin, conditioning_of

__all__ = ["register", "run_estimate", "run_payload_experiment"]

MODEL_HELP = ("a shipped robot name or robot YAML/URDF (its rigid-body model + friction, e.g. iiwa14_identified), "
              "an identified-model .npz written by `proprio identify`, or a hybrid model .pt written by `proprio "
              "train` (MLP-7/LSTM; its network runs online in the diagram, with its own training-time filters and "
              "rate, so --cutoff-hz does not apply to it)")


def _add_observer_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--gain", type=positive, default=100.0, help="momentum observer gain K_O [1/s] (default 100: time "
                   "constant 10 ms)")
    add_cutoff_hz(p, " for q and τ")
    p.add_argument("--force-only", action="store_true", help="estimate the 3-D force only (moment reported as 0); "
                   "right for a payload whose CoM is the contact point")
    p.add_argument("--sigma-threshold", type=nonnegative, default=0.02,
                   help="flag samples whose smallest Jacobian singular "
                   "value is below this as unreliable and damp them (default 0.02)")


def _options(args: argparse.Namespace):
    from proprio.systems.observers import WrenchMapping
    return (WrenchMapping(force_only=args.force_only, sigma_threshold=args.sigma_threshold,
                          damping_max=args.sigma_threshold), conditioning_of(args))


def run_estimate(args: argparse.Namespace) -> int:
    from proprio.diagrams.estimation import OBSERVERS, estimate_wrench, load_torque_model
    from proprio.recording import load_recording

    check_output(args.out, "--out", "dir")
    model = load_torque_model(args.model)
    rec = check_recording_robot(load_recording(args.recording), model.description, args.recording, "--model")
    mapping, conditioning = _options(args)
    res = estimate_wrench(model, rec, gain=args.gain, mapping=mapping, conditioning=conditioning)
    out = Path(args.out)
    title = f"{Path(args.recording).name}: estimated external force, model {res.meta['model']}"
    written = res.save(out) + [res.plot(out / "wrench.png", title=title)]
    if "line" in res.meta.get("conditioning", {}):
        print(res.meta["conditioning"]["line"])
    gaps = f", {res.gap.sum()} inside gaps of the log (no estimate: NaN)" if res.gap.any() else ""
    print(f"{res.t.size} samples{gaps}, {res.unreliable.sum()} flagged unreliable (near a singularity); statistics "
          f"over the {res.valid().sum()} valid ones")
    if not res.valid().any():
        print("no force statistics: no sample is clear of the transients at the ends and around the gaps")
    else:
        truth = res.f_true is not None
        print(f"{'observer':<10} {'RMS f̂ [fx fy fz] N':<28}"
              + (f" {'RMSE [fx fy fz] N':<28} {'σ [fx fy fz] N'}" if truth else "  (no true force in the recording)"))
        for obs in OBSERVERS:
            line = f"{obs:<10} {_vec(res.force_rms(obs)):<28}"
            if truth:
                rmse, std = res.force_stats(obs)
                line += f" {_vec(rmse):<28} {_vec(std)}"
            print(line)
    for path in written:
        print(f"wrote {path}")
    return 0


def _vec(v) -> str:
    return "[" + " ".join(f"{x:.2f}" for x in v) + "]"


def run_payload_experiment(args: argparse.Namespace) -> int:
    from proprio.experiments.payload import payload_experiment

    check_output(args.out, "--out", "dir")
    mapping, conditioning = _options(args)
    result = payload_experiment(args.model, args.out, seconds=args.seconds, masses=tuple(args.masses),
                                seed=args.seed, gain=args.gain, mapping=mapping, conditioning=conditioning,
                                twin_config=args.twin, progress=True)
    print(result.table_text)
    for path in result.files:
        print(f"wrote {path}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "estimate", help="estimate the external wrench at the flange over a Recording (both observers)",
        description="Replay a Recording through the estimation diagram (filtered derivatives → dynamics model → "
                    "Jacobian and momentum wrench observers) and write estimates.npz / estimates.csv and a plot of "
                    "f̂ against the recording's true f_ext (if it has one) to --out.")
    p.add_argument("--model", default="iiwa14_identified", help=MODEL_HELP + " (default iiwa14_identified)")
    p.add_argument("--recording", required=True, help="a Recording .npz (e.g. from `proprio simulate`)")
    p.add_argument("--out", required=True, help="output directory")
    _add_observer_options(p)
    p.set_defaults(func=run_estimate)

    p = subparsers.add_parser(
        "payload-experiment", help="thesis §5 payload experiment: 0 / 500 / 1000 g at the flange, Table 5.4",
        description="Run an RFMA validation trajectory on the calibrated twin with each payload mass at the flange, "
                    "estimate the external force with MODEL (without the payload) and print the RMSE and standard "
                    "deviation of the force error per axis, per mass and per observer (thesis Table 5.4), plus "
                    "figures and an error budget per twin effect.")
    p.add_argument("--model", default="iiwa14_identified", help=MODEL_HELP + " (default iiwa14_identified)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seconds", type=positive, default=30.0, help="duration of the validation trajectory [s] "
                   "(default 30; the thesis' Table 5.4 ran 563: 42260 samples at 75 Hz)")
    add_list(p, "--masses", type=nonnegative, default=[0.0, 0.5, 1.0], help="payload masses [kg] "
                   "(default 0 0.5 1)")
    p.add_argument("--seed", type=nonnegative_int, default=7, help="seed of the RFMA trajectory and the twin's noise")
    add_twin(p, "iiwa14_twin", ", the twin the payloads are simulated on (--twin-config: its former name)",
             "--twin-config")
    _add_observer_options(p)
    p.set_defaults(func=run_payload_experiment)
