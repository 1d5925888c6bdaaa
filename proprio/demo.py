"""``proprio demo``: the end-to-end pipeline on the built-in default, as a list of stages.

Each :class:`Stage` is a function ``run(ctx, out_dir) -> list[Path]`` that reads what earlier stages put in the shared
``ctx`` dict, adds its own results, prints a few lines and returns the files it wrote. :func:`run_demo` prints a header
per stage, times it and lists its outputs. Later capabilities insert their stages into :data:`STAGES`
(trajectory → twin → identification → observers → diagnosis → hybrid).

Current stages:

1. ``robot`` — load the twin robot ``iiwa14_identified`` (the robot the twin treats as real).
2. ``twin`` — a Drake diagram ``TrajectorySource → InverseDynamicsController → MultibodyPlant`` (discrete, 1 ms)
   tracks a smooth 5 s joint motion; ``VectorLogSink``s record q, q̇ and the controller's generalized force, which
   without joint effects is the link-side torque τ_J. Saved as a Recording.
3. ``inspect`` — the ``proprio inspect`` summary and plot of that Recording.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.controllers import InverseDynamicsController
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from proprio.description import RobotDescription, load_robot
from proprio.dynamics import inverse_dynamics
from proprio.io import atomic_write_text
from proprio.kinematics import flange_position
from proprio.plant import AddRobot, DrakeRobot
from proprio.recording import Recording, save_recording, validate_recording

__all__ = ["Stage", "STAGES", "run_demo", "demo_trajectory", "simulate_tracking", "DEFAULT_OUT"]

DEFAULT_OUT = Path("demo_output")
TWIN_ROBOT = "iiwa14_identified"

# A comfortable iiwa pose [rad] and three excursions from it; the motion starts and ends at rest in HOME.
HOME = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
EXCURSIONS = np.array([
    [0.5, 0.3, -0.4, 0.35, 0.6, -0.4, 0.7],
    [-0.4, -0.2, 0.4, -0.25, -0.6, 0.4, -0.7],
    [0.3, 0.25, -0.25, 0.3, 0.4, -0.3, 0.5],
])


@dataclass(frozen=True)
class Stage:
    """One demo step: ``run(ctx, out_dir)`` returns the paths it wrote."""
    name: str
    title: str
    run: Callable[[dict[str, Any], Path], list[Path]]


def demo_trajectory(duration: float = 5.0, home: np.ndarray = HOME,
                    excursions: np.ndarray = EXCURSIONS) -> PiecewisePolynomial:
    """A C²-continuous joint trajectory [rad] through ``home``, ``home + excursions[k]`` …, back to ``home``, at rest
    at both ends, with evenly spaced knots over ``duration`` [s]."""
    knots = np.vstack([home, home + excursions, home])                      # [K, n]
    breaks = np.linspace(0.0, duration, knots.shape[0])
    zero = np.zeros((knots.shape[1], 1))
    return PiecewisePolynomial.CubicWithContinuousSecondDerivatives(breaks, knots.T, zero, zero)


def simulate_tracking(desc: RobotDescription, trajectory: PiecewisePolynomial, time_step: float = 1e-3,
                      kp: float = 100.0, kd: float = 20.0) -> tuple[Recording, Diagram]:
    """Track ``trajectory`` with Drake's ``InverseDynamicsController`` on a discrete plant of ``desc``.

    Diagram: ``TrajectorySource [q_d; q̇_d; q̈_d] → Demultiplexer → InverseDynamicsController(kp, kd) → plant
    actuation``, plant state fed back; ``VectorLogSink``s sample the plant state and the controller torque every
    ``time_step``.
    Returns the Recording (t [s], q [rad], q̇ [rad/s], q̈ [rad/s²] = the plant's step acceleration
    (v_{k+1} − v_k)/h, τ [N·m]: the controller's generalized force, equal to the link-side τ_J since this plant has
    no joint effects, so τ = inverse_dynamics(q, q̇, q̈) to round-off) and the built diagram.
    """
    builder = DiagramBuilder()
    robot = AddRobot(builder, desc, time_step=time_step, finalize=False)
    plant = robot.plant
    plant.SetUseSampledOutputPorts(False)  # log the state of the current step, not a sampled copy
    plant.Finalize()
    n = desc.n
    control_model = DrakeRobot(desc).plant  # the controller's model: a separate continuous plant of the same robot
    source = builder.AddNamedSystem("trajectory", TrajectorySource(trajectory, output_derivative_order=2))
    split = builder.AddNamedSystem("split_reference", Demultiplexer([2 * n, n]))   # [q_d; q̇_d], q̈_d
    controller = builder.AddNamedSystem("controller", InverseDynamicsController(
        control_model, kp=np.full(n, kp), ki=np.zeros(n), kd=np.full(n, kd), has_reference_acceleration=True))
    state = plant.get_state_output_port(robot.instance)
    builder.Connect(source.get_output_port(), split.get_input_port())
    builder.Connect(split.get_output_port(0), controller.get_input_port_desired_state())
    builder.Connect(split.get_output_port(1), controller.get_input_port_desired_acceleration())
    builder.Connect(state, controller.get_input_port_estimated_state())
    builder.Connect(controller.get_output_port_generalized_force(), plant.get_actuation_input_port(robot.instance))
    state_log = LogVectorOutput(state, builder, publish_period=time_step)
    state_log.set_name("state_log")
    tau_log = LogVectorOutput(controller.get_output_port_generalized_force(), builder, publish_period=time_step)
    tau_log.set_name("tau_log")
    diagram = builder.Build()
    diagram.set_name("twin_tracking")

    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    plant.SetPositions(plant.GetMyMutableContextFromRoot(context), robot.instance, trajectory.value(0.0).ravel())
    simulator.AdvanceTo(trajectory.end_time() + time_step)  # one extra step to difference q̇ at the last sample

    xs = state_log.FindLog(context)
    t, x, tau = xs.sample_times(), xs.data().T, tau_log.FindLog(context).data().T
    # the discrete plant steps v_{k+1} = v_k + h·q̈_k, so the forward difference is the acceleration it integrated
    qdd = np.diff(x[:, n:], axis=0) / time_step
    k = min(len(t) - 1, int(round(trajectory.end_time() / time_step)) + 1)
    rec = Recording(t=t[:k].copy(), q=x[:k, :n].copy(), qd=x[:k, n:].copy(), qdd=qdd[:k].copy(), tau=tau[:k].copy(),
                    meta={"robot": desc.name, "rate_hz": 1.0 / time_step, "time_step_s": time_step,
                          "source": "proprio demo: InverseDynamicsController tracking on a discrete MultibodyPlant",
                          "controller": {"type": "InverseDynamicsController", "kp": kp, "kd": kd},
                          "effects": [], "payload": None})
    return validate_recording(rec, desc, source="demo recording"), diagram


# ---- stages -------------------------------------------------------------------------------------------------

def _stage_robot(ctx: dict[str, Any], out: Path) -> list[Path]:
    desc = load_robot(TWIN_ROBOT)
    ctx["robot"] = desc
    mass = sum(lk.mass for lk in desc.links)
    print(f"  {desc.name}: {desc.n} joints, moving mass {mass:.2f} kg, friction {'yes' if desc.has_friction else 'no'}")
    print(f"  flange at q = 0: {np.round(flange_position(desc, np.zeros(desc.n)), 4).tolist()} m")
    return []


def _stage_twin(ctx: dict[str, Any], out: Path) -> list[Path]:
    desc = ctx["robot"]
    traj = demo_trajectory()
    rec, diagram = simulate_tracking(desc, traj)
    ctx["recording"] = rec
    q_ref = traj.vector_values(rec.t).T
    err = np.abs(rec.q - q_ref).max()
    speed = (np.abs(rec.qd).max(axis=0) / desc.velocity_limits).max()
    print(f"  simulated {rec.duration:.2f} s at {rec.rate_hz:.0f} Hz: max tracking error {np.degrees(err):.3g}°, "
          f"peak speed {100 * speed:.0f} % of the joint limit, max |τ| {np.abs(rec.tau).max():.1f} N·m")
    rnea_gap = np.abs(rec.tau - inverse_dynamics(desc, rec.q, rec.qd, rec.qdd)).max()
    print(f"  check: max |τ − RNEA(q, q̇, q̈)| = {rnea_gap:.2g} N·m (numpy RNEA vs Drake's discrete plant)")
    rec_path = save_recording(rec, out / "twin_recording.npz")
    dot_path = out / "twin_diagram.dot"
    atomic_write_text(dot_path, diagram.GetGraphvizString(max_depth=1))
    ctx["recording_path"] = rec_path
    return [rec_path, dot_path]


def _stage_inspect(ctx: dict[str, Any], out: Path) -> list[Path]:
    from proprio.cli.inspect import format_summary, plot_recording, summarize_recording

    rec, desc = ctx["recording"], ctx["robot"]
    print("\n".join("  " + line for line in format_summary(summarize_recording(rec, desc)).splitlines()[1:]))
    return [plot_recording(rec, out / "twin_recording.png", desc, title="proprio demo: twin tracking")]


STAGES: list[Stage] = [
    Stage("robot", "twin robot description", _stage_robot),
    Stage("twin", "simulate the twin (Drake, 1 ms) and save a Recording", _stage_twin),
    Stage("inspect", "summarise and plot the Recording", _stage_inspect),
]


def run_demo(out_dir: str | Path = DEFAULT_OUT, stages: list[Stage] | None = None) -> dict[str, Any]:
    """Run ``stages`` (default :data:`STAGES`) in order with a shared context; returns the context, whose
    ``"outputs"`` maps each stage name to the files it wrote and ``"timings_s"`` to its wall time [s]."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stages = STAGES if stages is None else stages
    ctx: dict[str, Any] = {"out_dir": out, "outputs": {}, "timings_s": {}}
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
