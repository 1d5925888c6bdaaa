"""``proprio demo``: the whole pipeline on the built-in default, as a list of stages.

Each :class:`Stage` is a function ``run(ctx, out_dir) -> list[Path]`` that reads what earlier stages put in the shared
``ctx`` dict, adds its own results, prints a few lines and returns the files it wrote. :func:`run_demo` prints a header
per stage, times it and lists its outputs.

Stages (the built-in default is the calibrated iiwa 14 twin, ``proprio/configs/iiwa14_twin.yaml``):

1. ``trajectory`` — a short RFMA fine-motion trajectory (§4.3) and its Fig. 4.9 views.
2. ``twin`` — the calibrated twin (hysteresis, lost motion, friction, ripple, offsets, noise) on that trajectory:
   a Recording with truth channels, a Graphviz drawing of the diagram and the ``proprio inspect`` summary.
3. ``excitation`` — the twin on the shipped optimal Fourier excitation (§4.1; two speeds of the protocol).
4. ``identification`` — physically consistent (SDP) base parameters on the nominal kinematics from the excitation run, validated on
   the RFMA run (Table 4.4 layout).
5. ``payload`` — the payload experiment (§5, Table 5.4) with the identified RBD model and both observers.
6. ``diagnosis`` — the sim-to-real gap of the twin against the nominal CAD model: where, which effects, how far
   it shrinks (report.html), scored against the twin's truth; ``twin_patch.yaml`` and the held-out gap re-measured
   through the CAD twin with and without the patch.
7. ``hybrid`` — a small hybrid LSTM residual (§4.2): the one pretrained for this twin (``HYBRID_INIT``) fine-tuned
   on the twin data, scored against the RBD on a separate run, and the payload table with it.
8. ``view`` — Meshcat playbacks (:mod:`proprio.diagrams.playback`) of the twin run and of the heaviest payload run
   as self-contained HTML animations: the arm, estimated and true flange force, links tinted by the torque residual.

The sizes (seconds of motion, scaffolds, epochs) are a :class:`DemoSize`: :data:`FULL` is ``proprio demo``'s,
:data:`QUICK` (``proprio demo --quick``) runs every stage on a few seconds of data — the tests' run of the pipeline.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from proprio.description import load_robot
from proprio.io import atomic_write_text
from proprio.recording import save_recording

__all__ = ["Stage", "STAGES", "run_demo", "DEFAULT_OUT", "DemoSize", "FULL", "QUICK"]

DEFAULT_OUT = Path("demo_output")
TWIN = "iiwa14_twin"
NOMINAL_ROBOT = "iiwa14_nominal"
CAD_TWIN = "iiwa14_cad_twin"   # the nominal CAD robot as a twin: the base the diagnosis' twin_patch.yaml applies to
DIAGNOSIS_DOWNSAMPLE = 5     # 1 kHz -> 200 Hz for the diagnosis
HYBRID_DOWNSAMPLE = 7        # 1 kHz twin logs -> ≈143 Hz, the thesis' data rate (the model halves it again, §4.4)
HYBRID_INIT = "demo_residual.pt"   # proprio/configs/: the residual pretrained for this twin (README, "The demo")


@dataclass(frozen=True)
class DemoSize:
    """How much each stage runs: RFMA scaffolds, seconds [s] of motion simulated on the twin, protocol speeds of the
    excitation (fractions of the §4.1 speed, one period each), training epochs of the hybrid model."""
    rfma_scaffolds: int = 3
    twin_seconds: float = 40.0            # s of RFMA motion simulated on the twin (the 3 scaffolds last 33 s: all
                                          # of it; its first 30 s left the 0.1x lost motion unnamed; the 0.7x noise
                                          # is named from the raw τ's white floor on the joints whose residual is
                                          # structured only within the conditioning error: docs/guide/demo.md)
    excitation_speeds: tuple[float, ...] = (1.0, 0.8)   # the first two periods of the §4.1 protocol (20 s + 25 s)
    payload_seconds: float = 6.0          # s of motion per payload mass
    hybrid_epochs: int = 0               # fine-tuning epochs of the pretrained residual (README: fine-tuning on the
                                         # demo's 75 s made the held-out run worse and streaming worse than windowed)
    hybrid_payload_seconds: float = 20.0  # s of motion per payload mass of the hybrid's payload table


FULL = DemoSize()
QUICK = DemoSize(rfma_scaffolds=3, twin_seconds=20.0, excitation_speeds=(1.0, 0.8), payload_seconds=6.0,
                 hybrid_payload_seconds=6.0)


@dataclass(frozen=True)
class Stage:
    """One demo step: ``run(ctx, out_dir)`` returns the paths it wrote."""
    name: str
    title: str
    run: Callable[[dict[str, Any], Path], list[Path]]


def _indent(text: str) -> str:
    return "\n".join("  " + line for line in text.splitlines())


def _stage_trajectory(ctx: dict[str, Any], out: Path) -> list[Path]:
    from proprio.systems.rfma import demo_trajectory, plot_trajectory

    size: DemoSize = ctx["size"]
    traj, path = demo_trajectory(out, scaffolds=size.rfma_scaffolds, seed=0)
    ctx["rfma"] = traj
    desc = load_robot("iiwa14_identified")
    png = plot_trajectory(traj, desc, out / "rfma_demo.png", title="proprio demo: RFMA trajectory (Fig. 4.9 views)")
    print(f"  RFMA: {size.rfma_scaffolds} scaffolds, {traj.end_time():.1f} s of motion")
    return [path, png]


def _stage_twin(ctx: dict[str, Any], out: Path) -> list[Path]:
    from proprio.inspection import format_summary, plot_recording, summarize_recording
    from proprio.diagrams.twin import build_twin_diagram, load_twin_config, simulate_twin
    from proprio.systems.trajectories import truncate_trajectory

    cfg = load_twin_config(TWIN)
    traj = truncate_trajectory(ctx["rfma"], ctx["size"].twin_seconds)
    t0 = time.perf_counter()
    rec = simulate_twin(cfg, traj, progress=False)
    wall = time.perf_counter() - t0
    ctx["twin_config"], ctx["twin_rfma"], ctx["robot"] = cfg, rec, cfg.robot
    print(f"  simulated {rec.duration:.1f} s in {wall:.1f} s ({rec.duration / wall:.1f}× real time), "
          f"effects: {', '.join(rec.meta['effects'])}")
    print(_indent("\n".join(format_summary(summarize_recording(rec, cfg.robot)).splitlines()[1:])))
    rec_path = save_recording(rec, out / "twin_rfma.npz")
    dot = out / "twin_diagram.dot"
    atomic_write_text(dot, build_twin_diagram(cfg, traj).diagram.GetGraphvizString(max_depth=1))
    png = plot_recording(rec, out / "twin_rfma.png", cfg.robot, title="proprio demo: calibrated twin on RFMA")
    return [rec_path, dot, png]


def _stage_excitation(ctx: dict[str, Any], out: Path) -> list[Path]:
    from proprio.diagrams.twin import simulate_twin
    from proprio.identification.excitation import load_shipped_excitation, protocol_piecewise

    fourier, info = load_shipped_excitation()
    speeds = list(ctx["size"].excitation_speeds)
    traj = protocol_piecewise(fourier, speeds)
    rec = simulate_twin(ctx["twin_config"], traj, progress=False)
    ctx["twin_excitation"] = rec
    print(f"  shipped excitation: cond(K_b) = {info['cond']:.1f} (thesis 68); ran speeds {speeds} "
          f"→ {rec.duration:.1f} s on the twin")
    return [save_recording(rec, out / "twin_excitation.npz")]


def _stage_identification(ctx: dict[str, Any], out: Path) -> list[Path]:
    from proprio.identification.recordings import identify_recordings
    from proprio.identification.model_io import save_model

    # trim 0.1 s: the 100 samples at the twin's 1 kHz its figures were measured with (identify's --trim was samples)
    model, table = identify_recordings([ctx["twin_excitation"]], [ctx["twin_rfma"]], load_robot(NOMINAL_ROBOT),
                                       method="sdp", trim_s=0.1)
    ctx["identified_model_path"] = out / "identified_model.npz"
    save_model(model, ctx["identified_model_path"])
    print(f"  {model.method.upper()} on the nominal kinematics: {model.base.n_base} base parameters + offsets")
    print(_indent(table))
    atomic_write_text(out / "identification.txt", table + "\n")
    return [ctx["identified_model_path"], out / "identification.txt"]


def _stage_payload(ctx: dict[str, Any], out: Path) -> list[Path]:
    from proprio.experiments.payload import demo_payload_experiment

    exp = demo_payload_experiment(ctx["identified_model_path"], out / "payload_rbd",
                                  seconds=ctx["size"].payload_seconds)
    ctx["payload_rbd"], ctx["payload_table_rbd"] = exp, exp.table_text
    print(_indent(exp.table_text))
    return [out / "payload_rbd" / "table.txt"]


def _stage_diagnosis(ctx: dict[str, Any], out: Path) -> list[Path]:
    from proprio.diagrams.twin import load_twin_config
    from proprio.diagnosis import diagnose

    step = DIAGNOSIS_DOWNSAMPLE
    result = diagnose(load_robot(NOMINAL_ROBOT), [ctx["twin_excitation"].downsample(step)],
                      [ctx["twin_rfma"].downsample(step)], out / "diagnosis", twin=load_twin_config(CAD_TWIN))
    print(_indent(result.verdict))
    if result.replay is not None:
        floor = float(np.sqrt(np.mean(ctx["twin_config"].effect("torque_noise").std ** 2)))
        after = result.replay.total(result.replay.rms_after)
        print(_indent(f"{CAD_TWIN} + twin_patch.yaml, {result.replay.text()}; the twin's torque-noise floor is "
                      f"{floor:.3f} N·m RMS (after / floor = {after / floor:.2f})."))
    if result.truth is not None:
        print(_indent("Against the twin's truth: " + result.truth.markdown(result.attribution.joint_names)
                      .splitlines()[0] + " Fitted vs true parameters: diagnosis/report.md."))
    return list(result.files.values())


def _stage_hybrid(ctx: dict[str, Any], out: Path) -> list[Path]:
    import dataclasses
    import importlib.resources

    from proprio.diagrams.estimation import estimate_wrench, load_torque_model
    from proprio.experiments.payload import validation_trajectory
    from proprio.diagrams.twin import simulate_twin
    from proprio.experiments.hybrid import demo_hybrid
    from proprio.payload import Payload
    from proprio.systems.observers import WrenchMapping

    step, size = HYBRID_DOWNSAMPLE, ctx["size"]
    traj = validation_trajectory(size.hybrid_payload_seconds, seed=11)
    payload_recs = {}
    for k, mass in enumerate((0.0, 1.0)):
        run = dataclasses.replace(ctx["twin_config"], seed=ctx["twin_config"].seed + 100 + k)
        rec = simulate_twin(run.with_payload(Payload(mass) if mass else None), traj, progress=False)
        payload_recs[f"{int(mass * 1000)} g"] = rec.downsample(step)
    train = [ctx["twin_rfma"].downsample(step), ctx["twin_excitation"].downsample(step)]
    with importlib.resources.as_file(importlib.resources.files("proprio.configs") / HYBRID_INIT) as init:
        model, text = demo_hybrid(train, [payload_recs["0 g"]], str(ctx["identified_model_path"]), out,
                                  epochs=size.hybrid_epochs, payload_recs=payload_recs, init=init)
    seconds = sum(r.duration for r in train)
    tuned = (f"fine-tuned on the demo's {seconds:.0f} s for {size.hybrid_epochs} epochs" if size.hybrid_epochs else
             f"kept per joint where it beats the backbone on the validation split of the demo's {seconds:.0f} s "
             "(no fine-tuning)")
    print(f"  hybrid {model.cfg.label()} on the identified RBD backbone: the residual pretrained on 41 min of RFMA "
          f"on this twin (proprio/configs/{HYBRID_INIT}) {tuned}; test = a separate RFMA run "
          f"({size.hybrid_payload_seconds:g} s, raw τ); "
          "payload forces from the "
          "Jacobian observer (force-only)")
    # the same model online: its network stepped inside the estimation diagram, state carried sample to sample
    res = estimate_wrench(load_torque_model(out / "hybrid_lstm.pt"), payload_recs["1000 g"],
                          mapping=WrenchMapping(force_only=True))
    jac, mom = (" ".join(f"{x:.2f}" for x in res.force_stats(obs)[0]) for obs in ("jacobian", "momentum"))
    text += (f"\n\nOnline: the model inside the estimation diagram (backbone, then ResidualNetworkSystem, "
             f"{res.t.size} steps), "
             f"1000 g: force-only RMSE [{jac}] N (Jacobian observer), [{mom}] N (momentum observer), after "
             f"{res.skip_start_s:.1f} s of filter start-up")
    print(_indent(text))
    atomic_write_text(out / "hybrid.txt", text + "\n")
    return [out / "hybrid_lstm.pt", out / "hybrid.txt"]


def _stage_view(ctx: dict[str, Any], out: Path) -> list[Path]:
    from proprio.diagrams.estimation import load_torque_model
    from proprio.diagrams.playback import playback_from_estimate, playback_from_recording, write_playback_html

    model = load_torque_model(ctx["identified_model_path"])
    exp = ctx["payload_rbd"]
    mass = max(exp.masses)
    grams = int(round(mass * 1000))
    runs = [(playback_from_recording(ctx["twin_rfma"], model, title="proprio demo: calibrated twin on RFMA, forces "
                                     "and residuals of the identified RBD model"), "twin_rfma.html"),
            (playback_from_estimate(exp.results[mass], model.description, title=f"proprio demo: {grams} g at the "
                                    "flange, identified RBD model"), f"payload_{grams}g.html")]
    paths = []
    for pb, name in runs:
        path, info = write_playback_html(pb, out / name)
        print(f"  {name}: {pb.t[-1] - pb.t[0]:.1f} s in {info.frames.count} frames, link tint ±"
              f"{info.residual_scale:.2f} N·m, {path.stat().st_size / 1e6:.1f} MB")
        paths.append(path)
    return paths


STAGES: list[Stage] = [
    Stage("trajectory", "RFMA fine-motion trajectory (§4.3)", _stage_trajectory),
    Stage("twin", "calibrated twin on the RFMA trajectory (Drake, 1 ms)", _stage_twin),
    Stage("excitation", "calibrated twin on the optimal excitation (§4.1)", _stage_excitation),
    Stage("identification", "rigid-body identification: train on excitation, validate on RFMA", _stage_identification),
    Stage("payload", "payload experiment with the identified RBD model (Table 5.4)", _stage_payload),
    Stage("diagnosis", "sim-to-real gap of the twin against the nominal CAD model", _stage_diagnosis),
    Stage("hybrid", "hybrid LSTM residual on the identified backbone, and its payload table", _stage_hybrid),
    Stage("view", "Meshcat playback of the twin run and the payload run (self-contained HTML)", _stage_view),
]


def run_demo(out_dir: str | Path = DEFAULT_OUT, stages: list[Stage] | None = None,
             size: DemoSize = FULL) -> dict[str, Any]:
    """Run ``stages`` (default :data:`STAGES`) in order with a shared context (``ctx["size"]`` is ``size``); returns
    the context, whose ``"outputs"`` maps each stage name to the files it wrote and ``"timings_s"`` to its wall time
    [s]."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stages = STAGES if stages is None else stages
    ctx: dict[str, Any] = {"out_dir": out, "size": size, "outputs": {}, "timings_s": {}}
    t_all = time.perf_counter()
    for k, stage in enumerate(stages, 1):
        print(f"\n== [{k}/{len(stages)}] {stage.name}: {stage.title}", flush=True)
        t0 = time.perf_counter()
        paths = stage.run(ctx, out)
        ctx["outputs"][stage.name] = paths
        ctx["timings_s"][stage.name] = dt = time.perf_counter() - t0
        for p in paths:
            print(f"  -> {p}")
        print(f"  ({dt:.1f} s)", flush=True)
    print(f"\ndemo finished in {time.perf_counter() - t_all:.1f} s; outputs in {out.resolve()}")
    return ctx
