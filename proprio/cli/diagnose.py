"""``proprio diagnose`` (sim-to-real torque-gap diagnosis of measured recordings) and ``proprio gap-benchmark``
(the withheld-effect benchmark of that diagnosis)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from proprio.cli import (UserError, add_chain_args, add_plugin_args, check_output, check_recording_robot, load_robot_arg,
                         nonnegative_int)
from proprio.cli._backend import add_backend_args, check_backend_args, clear_state
from proprio.cli.flags import add_cutoff_hz, add_list, add_split, add_trim, add_twin, conditioning_of, split_tails

HOLDOUT_FRACTION = 1 / 3
"""The share of every training recording held out at its end when no --holdout is given (the README's TX40 split:
6 s of 9 train, 3 s held out)."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose", help="where the sim-to-real torque gap lies, which unmodelled effect causes it, how far it shrinks",
        description="Fit every candidate effect the simulation model lacks (the twin's joint-effect library, "
        "rigid-body parameter error, payload, signal lag) to the residual τ_meas − τ_sim of the training "
        "recordings, score each by the reduction of the residual on the held-out recordings, add the best while "
        "the gain is significant, and write report.html / report.md to --out.")
    p.add_argument("--model", required=True,
                   help="simulation model: a built-in robot name (iiwa14_nominal, ...), a robot YAML/URDF, a "
                   "directory with robot.yaml (e.g. ../shared/data/kuka_lwr4), or an identified model .npz written "
                   "by `proprio identify` (its inertials, friction and offsets)")
    add_chain_args(p)
    add_list(p, "--effects", nargs="*", default=[], metavar="EFFECT",
             help="effects the simulation already has: library names or your own effects as 'package.module:Class' "
             "(at the parameters of --effects-config, else the class defaults)")
    p.add_argument("--effects-config", type=Path, help="YAML with an 'effects:' mapping {name: parameters}")
    add_list(p, "--train", required=True, type=Path, metavar="REC",
             help="training recordings (.npz Recording or FloBaRoID LWR measurement files); without --holdout the "
             "end of each is held out (--holdout-fraction, --split-at)")
    add_list(p, "--holdout", nargs="*", default=[], type=Path, metavar="REC",
             help="held-out recordings; without them the end of every training recording is held out (each part "
             "must keep enough for the block test after trimming: a shorter log is refused up front with the "
             "seconds it would need)")
    add_split(p, None, f"{HOLDOUT_FRACTION:.3g} without --holdout")
    add_cutoff_hz(p)
    add_list(p, "--candidates", nargs="*", metavar="NAME", help="test only these candidates")
    p.add_argument("--candidate", action="append", default=[], metavar="MODULE:CLASS",
                   help="your own effect (a proprio.effects.JointEffect subclass, README 'Your own effect') tested "
                   "alongside the library candidates; repeatable")
    add_trim(p, None, "0.5, at most 5 %% of a recording's length but never less than its low-pass's settling, 3 "
             "periods of the lowest cutoff")
    add_twin(p, None, " of the --model robot, the base: replay the held-out recordings through it and through it + "
             "twin_patch.yaml, and report the gap through the twin next to the offline prediction")
    p.add_argument("--out", required=True, type=Path, help="output directory for the report and twin_patch.yaml")
    p.add_argument("--design-experiment", action="store_true",
                   help="for every tied set of effects (the report's ambiguity section) design the motion that "
                   "separates them (≤ 60 s, within the limits, collision-checked) and write it to "
                   "OUT/experiment_<A>_vs_<B>.npz, the format of 'proprio trajectory': run it on the robot, then "
                   "diagnose again with --experiment REC")
    add_list(p, "--experiment", default=[], type=Path, metavar="REC",
                   help="recordings of designed experiments: each is cut between its two mirrored passes (at its "
                   "middle); the first pass joins the training recordings, the second the held-out ones")
    p.add_argument("--resolve", metavar="TWIN",
                   help="twin data: design the experiments (--design-experiment), run them on this twin config (the "
                   "twin that made the data), diagnose again with the old recordings plus the new ones into "
                   "OUT/resolved/ and say which tied sets are resolved (OUT/resolution.json)")
    add_plugin_args(p)
    p.set_defaults(func=_diagnose)

    b = sub.add_parser(
        "gap-benchmark", help="withheld-effect benchmark of the gap diagnosis",
        description="Generate data with an effect the model lacks (every effect type, several magnitudes and "
        "seeds; null and two-effect cases), diagnose without being told, and print the confusion matrix, "
        "top-1/top-2 accuracy, null false-positive rate and shrinkage-prediction error. By default the data are "
        "made offline (closed-form RFMA-like motion + rigid-body torque + the effect library); --twin simulates "
        "them with the Drake twin diagram instead.")
    b.add_argument("--twin", action="store_true",
                   help="record every case with the twin diagram (iiwa14_twin with the case's effects, or payload, "
                   "on short RFMA trajectories, logged at 200 Hz with jittered stamps); covers the twin's effects "
                   "(viscous_coulomb, hysteresis, lost_motion, ripple, sensor_offset_gain, torque_noise, "
                   "encoder_noise) and payload; slower (~30 s of CPU per case)")
    b.add_argument("--drive", action="store_true",
                   help="the drive-torque family instead: an arm without joint-torque sensors (τ = drive torque) "
                   "through the twin, withheld rotor inertia, pre-sliding friction, motor friction or drive offsets, "
                   "logged at 100 Hz and 1 kHz with jittered stamps (proprio.gap_benchmark.drive)")
    b.add_argument("--quick", action="store_true", help="one magnitude per effect type, 2 null, 1 two-effect case "
                   "(with --twin: 4 effect types, 1 null, 1 two-effect case), 1 out-of-library and 1 time-varying "
                   "case")
    add_list(b, "--cases", metavar="NAME", default=None,
                   help="run only these cases of the list (names as in benchmark.txt, e.g. viscous_coulomb@1 null#0; "
                   "the scores then cover only them)")
    b.add_argument("--out", required=True, type=Path,
                   help="directory for benchmark.txt / benchmark.json; OUT/cases/ keeps one result file per finished "
                   "case, so a rerun (after a kill) runs only the missing cases")
    b.add_argument("--confusable", action="store_true",
                   help="the confusable-pairs family instead (hysteresis vs Coulomb, pre-sliding vs lost motion, "
                   "load-dependent friction vs sensor gain, payload vs rigid body; --twin: through the twin): each case is diagnosed, the experiment of "
                   "every tied set designed and recorded, and diagnosed again; prints the share right or tied before "
                   "and top-1 after (OUT/confusable.txt, OUT/confusable.json)")
    b.add_argument("--seed", type=nonnegative_int, default=0, help="seed of the case list (default 0)")
    add_backend_args(b, "os.cpu_count() for local, the Ray cluster's CPUs for ray")
    add_plugin_args(b)
    b.set_defaults(func=_benchmark)


def _effects_config(path: Path, n: int) -> dict:
    """The effects mapping of an ``--effects-config`` file — a twin config or patch (its ``effects:`` block) or a bare
    ``{name: parameters}`` mapping — checked strictly against the effect classes for ``n`` joints
    (:mod:`proprio.effects.schema`: a misspelt name or field names the nearest valid one)."""
    from proprio.effects.schema import check_effects_block
    from proprio.typed_yaml import read_yaml

    if not path.is_file():
        raise UserError(f"--effects-config: no such file {path}")
    data = read_yaml(path, error=UserError) or {}
    if not isinstance(data, dict):
        raise UserError(f"--effects-config {path}: expected a mapping (a twin config or {{effect: parameters}})")
    where = f"{path}: effects" if "effects" in data else str(path)
    config = data["effects"] if "effects" in data else data
    check_effects_block(config, n, where, UserError)
    return config or {}


def _model(args: argparse.Namespace):
    from proprio.diagnosis.data import SimModel, identified_robot
    from proprio.effects import make_effects

    config: dict = {}
    try:
        robot, identified = identified_robot(args.model) if str(args.model).endswith(".npz") else \
            (load_robot_arg(args.model, args), {})
    except (FileNotFoundError, KeyError, ValueError) as exc:
        raise UserError(f"--model: cannot load robot {args.model!r} ({exc})") from exc
    if args.effects_config:
        config = _effects_config(args.effects_config, robot.n)
    chosen = {k: config.get(k) for k in args.effects}
    chosen.update({k: v for k, v in identified.items() if k not in chosen})     # the identified offsets
    if robot.has_friction and "viscous_coulomb" in chosen:
        raise UserError(f"friction given twice: the robot file of --model {args.model!r} already has link friction "
                        "(friction.viscous / friction.coulomb) and --effects names viscous_coulomb; drop one")
    try:
        return SimModel(robot, tuple(make_effects(chosen, robot.n)))
    except ValueError as exc:
        raise UserError(f"--effects: {exc}") from exc


def _hold_out_tails(args: argparse.Namespace, train: list, hold: list) -> tuple[list, list]:
    """``--split-at`` / ``--holdout-fraction`` (the latter by default when no --holdout is given): the end of every
    training recording is held out; said in the output. Refused before any work when a part is too short for the block
    test after trimming (``MIN_BLOCKS`` blocks of ≥ ``MIN_BLOCK_S``, :mod:`proprio.diagnosis.data`, the number the
    diagnosis itself refuses a held-out set below), with the seconds the log would need."""
    from proprio.diagnosis.data import MAX_TRIM_S, MIN_BLOCK_S, MIN_BLOCKS, TRIM_SHARE

    default = not args.holdout and args.split_at is None and args.holdout_fraction is None
    if default:
        args.holdout_fraction = HOLDOUT_FRACTION
    heads, tails, names = split_tails(args, train, args.train)
    if not tails:
        return train, hold
    how = (f"all after the first {args.split_at:g} s (--split-at)" if args.split_at is not None else
           f"the last {100 * args.holdout_fraction:.3g} % (--holdout-fraction {args.holdout_fraction:.3g}"
           f"{', the default without --holdout' if default else ''})")
    print(f"held out: {how} of every --train recording: " + ", ".join(names))
    least = MIN_BLOCKS * MIN_BLOCK_S
    for role, parts in (("held-out", tails), ("training", heads)):
        spans = [float(r.t[-1] - r.t[0]) for r in parts]
        # the trim is the given one, or at least the default's share of a short recording (data.default_trim_s)
        usable = sum(s - 2 * (args.trim if args.trim is not None else min(MAX_TRIM_S, TRIM_SHARE * s))
                     for s in spans)
        if usable < least:
            total = sum(float(r.t[-1] - r.t[0]) for r in train)
            share = sum(spans) / total
            trim = 2 * len(spans) * (args.trim if args.trim is not None else 0.0)
            part = (least + trim) / (1 - (2 * TRIM_SHARE if args.trim is None else 0.0))
            need = (f"a held-out part of ≥ {part:.1f} s: record ≥ {args.split_at + part / len(spans):.1f} s"
                    if args.split_at is not None and role == "held-out" else
                    f"a {role} part of ≥ {part:.1f} s: record ≥ {part / share:.1f} s at this split")
            raise UserError(
                f"--train: the {role} part is {sum(spans):.2f} s ({usable:.2f} s after trimming) of {total:.2f} s "
                f"recorded; the block test needs ≥ {least:g} s ({MIN_BLOCKS} blocks of ≥ {MIN_BLOCK_S:g} s) "
                f"after trimming, so {need}; or move the split (--holdout-fraction, --split-at) or give held-out "
                "recordings (--holdout REC)")
    return heads, hold + tails


# candidates of the diagnosis that are not joint effects (proprio.diagnosis.candidates.registry.candidate_set)
_NON_EFFECT_CANDIDATES = ("rigid_body", "payload", "signal_lag", "sensor_offset", "sensor_gain", "rotor_inertia",
                          "motor_friction", "drive_offset")     # the last three: drive-torque arms only


def _diagnose(args: argparse.Namespace) -> int:
    from proprio.diagnosis.data import DIAGNOSIS_CONDITIONING
    from proprio.effects import EFFECTS, allow_plugins, resolve_effect
    from proprio.effects.plugins import is_plugin_path
    from proprio.identification.recordings import check_tau_kind
    from proprio.progress import progress_bar
    from proprio.recording import load_recording

    check_output(args.out, "--out", "dir")
    unknown = [k for k in args.candidates or () if k not in EFFECTS and k not in _NON_EFFECT_CANDIDATES
               and not is_plugin_path(k)]
    if unknown:                                     # before any data are read (the diagnosis checks them again)
        raise UserError(f"--candidates: unknown {unknown}; valid: {sorted([*EFFECTS, *_NON_EFFECT_CANDIDATES])} or "
                        "a plugin 'package.module:Class'")
    # plugins named on the command line itself are the user's consent; a config's are not (--allow-plugin)
    allow_plugins([name for name in args.candidate + args.effects if is_plugin_path(name)])
    conditioning = conditioning_of(args, DIAGNOSIS_CONDITIONING)
    model = _model(args)
    for name in args.candidate:                     # a bad plugin is refused before any data are read
        try:
            resolve_effect(name)
        except ValueError as exc:
            raise UserError(f"--candidate: {exc}") from exc
    twin = None
    if args.twin is not None:
        from proprio.diagrams.twin import TwinConfigError, load_twin_config

        try:
            twin = load_twin_config(args.twin)
        except TwinConfigError as exc:
            raise UserError(f"--twin: {exc}") from exc
        if twin.robot.name != model.robot.name or twin.robot.n != model.robot.n:
            raise UserError(f"--twin: the twin's robot is '{twin.robot.name}' ({twin.robot.n} joints), --model is "
                            f"'{model.robot.name}' ({model.robot.n} joints)")
    resolve_twin = _resolve_twin(args.resolve, model) if args.resolve else None
    load = lambda p: check_recording_robot(load_recording(p, model.robot), model.robot, p, "--model")  # noqa: E731
    train = [load(p) for p in args.train]
    hold = [load(p) for p in args.holdout]
    try:                                           # what τ is decides the candidates: the Recordings must agree
        check_tau_kind(train + hold, list(args.train) + list(args.holdout), model.robot)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    train, hold = _hold_out_tails(args, train, hold)
    if args.experiment:
        from proprio.diagnosis.resolve import with_experiments

        try:
            train, hold = with_experiments(train, hold, [load(p) for p in args.experiment])
        except ValueError as exc:
            raise UserError(f"--experiment: {exc}") from exc
    from proprio.diagnosis import diagnose          # the whole diagnosis only once the data passed every check

    bar = progress_bar(desc="diagnose", bar_format="{desc}: {elapsed} {postfix}")
    try:
        d = diagnose(model, train, hold, args.out, candidates=args.candidates, trim_s=args.trim,
                     progress=lambda msg: bar.set_postfix_str(msg), conditioning=conditioning, twin=twin,
                     plugins=args.candidate)
    finally:
        bar.close()
    for line in d.attribution.conditioning:
        print(line)
    print(d.verdict)
    for line in d.advice:
        print(f"advice: {line}")
    for line in d.failures:                        # the rest was written: the run keeps its answer (exit 0)
        print(f"proprio: warning: {line}", file=sys.stderr)
    if d.replay is not None:
        print(d.replay.text())
    if args.experiment:
        from proprio.diagnosis.resolve import refit_jointly, training_data

        refit = refit_jointly(d.attribution, training_data(model, train, conditioning, args.trim))
        if refit is not None:
            print(refit.text())
    if "twin_patch" in d.files:
        print(f"twin patch: {d.files['twin_patch']}")
    print(f"report: {d.files.get('report_html', d.files['json'])}")
    if args.design_experiment or resolve_twin is not None:
        _experiments(args, model, d, train, hold, conditioning, resolve_twin)
    return 0


def _resolve_twin(name: str, model):
    """The twin config of ``--resolve`` (its robot must be the model's)."""
    from proprio.diagrams.twin import TwinConfigError, load_twin_config

    try:
        twin = load_twin_config(name)
    except (TwinConfigError, OSError) as exc:
        raise UserError(f"--resolve: {exc}") from exc
    if twin.robot.n != model.robot.n:
        raise UserError(f"--resolve: the twin's robot has {twin.robot.n} joints, --model {model.robot.n}")
    return twin


def _experiments(args: argparse.Namespace, model, d, train, hold, conditioning, twin) -> None:
    """--design-experiment / --resolve: the experiments of the tied sets, and with a twin the re-diagnosis."""
    from proprio.diagnosis.discriminate import resolution
    from proprio.diagnosis import diagnose
    from proprio.diagnosis.resolve import (design_experiments, refit_jointly, run_on_twin, training_data,
                                           with_experiments, write_resolution)

    designed = design_experiments(model, d.attribution, args.out,
                                  train=training_data(model, train, conditioning, args.trim))
    if not designed:
        print("no tied effects: no experiment needed")
        return
    for de in designed:
        print(f"experiment: {de.text()}")
    resolutions, refit = [], None
    if twin is not None:
        recs = run_on_twin(twin, designed)
        if recs:
            train2, hold2 = with_experiments(train, hold, recs, [de.experiment.split_s for de in designed
                                                                 if de.recording is not None])
            d2 = diagnose(model, train2, hold2, args.out / "resolved", candidates=args.candidates, trim_s=args.trim,
                          conditioning=conditioning, plugins=args.candidate)
            resolutions = resolution(d.attribution.ambiguity, d2.attribution.ambiguity)
            print(f"with the experiment(s): {d2.verdict}")
            for r in resolutions:
                print(f"resolution: {r.text}")
            refit = refit_jointly(d2.attribution, training_data(model, train2, conditioning, args.trim), twin.effects)
            if refit is not None:
                print(refit.text())
            print(f"report after the experiment(s): {d2.files['report_html']}")
    print(f"experiments: {args.out / 'resolution.json'}")
    write_resolution(args.out / "resolution.json", designed, resolutions, refit)


def _benchmark(args: argparse.Namespace) -> int:
    from proprio.gap_benchmark.run import run_benchmark, write_results
    from proprio.gap_benchmark.cases import make_cases, select_cases

    check_output(args.out, "--out", "dir")
    check_backend_args(args)
    if args.confusable:
        return _confusable(args)
    if args.drive:
        from proprio.gap_benchmark.drive import drive_cases
        cases = select_cases(drive_cases(quick=args.quick, seed=args.seed), args.cases)
    else:
        cases = select_cases(make_cases(quick=args.quick, seed=args.seed, twin=args.twin), args.cases)
    results = run_benchmark(cases, workers=args.workers, backend=args.backend, address=args.address,
                            state_dir=clear_state(args.out / "cases", args.restart))
    _, text = write_results(results, args.out)
    print(text)
    return 0


def _confusable(args: argparse.Namespace) -> int:
    """``gap-benchmark --confusable``: the confusable-pairs family, before and after the designed experiment."""
    import json
    from concurrent.futures import ProcessPoolExecutor
    from dataclasses import asdict

    from proprio.gap_benchmark.cases import select_cases
    from proprio.gap_benchmark.confusable import confusable_cases, run_confusable_case, summarise_confusable
    from proprio.io import atomic_write_text

    cases = select_cases(confusable_cases(seed=args.seed, magnitudes=(1.0,) if args.quick else (0.5, 1.0, 2.0),
                                          twin=args.twin), args.cases)
    results = []
    with ProcessPoolExecutor(max_workers=args.workers or 1) as pool:
        for r in pool.map(run_confusable_case, cases):          # in order; each case printed as it is done
            results.append(r)
            print(summarise_confusable([r])[1].splitlines()[1], flush=True)
    scores, text = summarise_confusable(results)
    atomic_write_text(args.out / "confusable.txt", text + "\n")
    atomic_write_text(args.out / "confusable.json", json.dumps({"scores": scores,
                                                                "cases": [asdict(r) for r in results]}, indent=1))
    print(text)
    return 0
