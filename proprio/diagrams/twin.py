"""The twin: the data-collection diagram that plays the role of the real robot (DESIGN.md, "Physics of the twin").

``JointTrajectorySource → DiscreteInverseDynamicsController → drive (motor side + link friction: a C++ FrictionDrive, the
Python JointDrive, or for a coupled wrist the CoupledDrive: proprio.systems.joint_drive) → MultibodyPlant
(discrete 1 ms, payload) → measurement chain``: the plant's true motion enters a compiled shift register and, once
per block of 1 000 steps, the log sampler, the transmitted torque, the torque sensor, the encoder and the robot's
logger (lost samples, jittered stamps, the channels the robot reports) apply their laws to the block, in the Diagram
(:mod:`proprio.diagrams.twin_chain`). Output: a :class:`~proprio.recording.Recording` — what the Diagram's robot
logger wrote — whose measured channels are what that robot logs: stamps ``t``, encoder ``q``, ``tau`` (τ_J) and,
only for a robot that reports one, its own filtered ``qd``; never ``qdd`` — plus the true flange wrench ``f_ext``
(for scoring) and truth channels:

* ``tau_rbd``: rigid-body torque of the logged motion incl. payload, the plant's own dynamics in each step
  (``DriveLaw.rigid_body_torque``: net actuation less the rotor inertia the plant carries; equal to
  ``proprio.dynamics.inverse_dynamics`` of the logged motion to 1e-6 N·m, tests);
* ``tau_J_true``: the transmitted, sensed torque before the sensor effects, straight from the simulation
  (``DriveLaw.sensed_torque``: actuation + link friction [− B q̈ for a rigid drive]); it equals
  ``tau_rbd + Σ link friction`` to solver precision (tests: 1e-6 N·m);
* ``tau_<effect>``: each effect's contribution (``tau_viscous_coulomb``, ``tau_hysteresis``, ...);
* ``q_true``, ``qd``, ``qdd``: the plant's exact link position, velocity and acceleration at the true sampling
  instants ``t_true`` (on the clock of ``t``); ``q_motor``, ``qd_motor``: θ, θ̇ of an elastic drive.

Every random draw (each sensor effect's noise, the encoder's, the logger's losses, burst lengths and stamp jitter) has
its own stream under the config's ``seed`` (:mod:`proprio.random_streams`), so the chain's blocks draw what the whole
run would, and one effect's draws do not change when another is added.

Every stage gets q̇, q̈ from the one conditioning path (:mod:`proprio.conditioning`); truth serves scoring only. The
motor side (``drive`` block, ``elasticity``) has no torque channel: it is
hidden behind the sensor and acts only through the motion.

A twin is described by one YAML file (``proprio/configs/iiwa14_twin.yaml``)::

    name: iiwa14_twin
    robot: iiwa14_identified          # built-in name or robot YAML path
    time_step: 0.001                  # s, discrete plant and drive period
    seed: 7
    session_time_s: 0.0               # s, the session clock at the run's t = 0 (time-varying effects see t + it)
    logger: {rate_hz: 1000, channels: [q, tau], stamp_jitter_ms: 0.1, dropout_prob: 0.002}   # see robot_log
    controller: {kp: [...], ki: [...], kd: [...], payload_model: false}   # IDC gains (1/s², 1/s³, 1/s)
    drive: {motor_inertia: [...], motor_viscous: [...], motor_coulomb: [...]}   # motor side (hidden), or null
    payload: {mass: 1.0, com_flange: [0, 0, 0.05]}                        # or null
    effects: {viscous_coulomb: {...}, hysteresis: {...}, ...}             # see proprio.effects
    # user-defined effects (proprio.effects.plugins) by their dotted path, e.g.
    #   effects: {"my_package.my_effects:CableSpring": {stiffness: [0.5, 0, 0, 0, 0, 0, 0]}}
    # link-side plugins act in the JointDrive (on t, q, q̇), sensor-side ones in the TorqueSensor

Every effect's contribution is logged as ``tau_<name>`` (a plugin's ``name`` class attribute).

``robot`` may also be a robot mapping (the ``proprio-robot/v1`` layout of ``RobotDescription.to_dict``).

**Patches.** A twin patch (``twin_patch.yaml``, written by ``proprio diagnose``) is a fragment of this format that
adds what a diagnosis found to a base twin: ``patch_for: {robot: <name>, joints: <n>}`` (the robot it was fitted
for), ``effects:`` blocks, a ``payload:`` and/or a corrected ``robot:`` (a robot YAML path, relative to the patch's
folder, or a mapping). :func:`merge_twin_patch` merges it into the base config's mapping and
``load_twin_config(base, patch=...)`` loads the result; an effect the base already simulates, a payload on a base
that has one, or a patch for another robot or joint count is an error naming the field.
"""
from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.trajectories import PiecewisePolynomial, Trajectory
from proprio.progress import progress_bar

from proprio.description import RobotDescription
from proprio.dynamics import inverse_dynamics
from proprio.payload import Payload, attach_payload
from proprio.plant import DrakeRobot, robot_plant
from proprio.recording import Recording
from proprio.systems.joint_drive import (
    AddJointDrive, DriveLaw, check_elastic_stability, check_explicit_friction, friction_slope, reflected_inertia,
)
from proprio.identification.regressor import drive_identified
from proprio.effects import Elasticity
from proprio.robot_log import LoggerCarry
from proprio.systems.controller import AddDiscreteInverseDynamicsController, DiscreteInverseDynamicsController
from proprio.systems.trajectories import AddTrajectorySource, sample_positions
from proprio.diagrams.twin_chain import AddMeasurementChain, MeasurementChain, payload_wrench, run_steps
from proprio.diagrams.twin_config import (  # noqa: F401  (re-exported: callers import them from here)
    PATCH_KEYS, TwinConfig, TwinConfigError, load_twin_config, merge_twin_patch,
)

__all__ = ["TwinConfig", "TwinConfigError", "load_twin_config", "merge_twin_patch", "PATCH_KEYS", "TwinDiagram",
           "build_twin_diagram", "start_simulator", "simulate_twin", "payload_wrench", "hysteresis_test_trajectory",
           "run_hysteresis_test"]


# ------------------------------------------------------------------------------------------------------------------
# the diagram
# ------------------------------------------------------------------------------------------------------------------
@dataclass
class TwinDiagram:
    """What :func:`build_twin_diagram` returns."""
    diagram: Diagram
    plant: Any
    drive: DriveLaw                # FrictionDrive, JointDrive or CoupledDrive
    controller: DiscreteInverseDynamicsController
    chain: MeasurementChain | None  # sensors and logger on [q; q̇; net actuation (; θ; θ̇ if elastic)]; None:
    config: TwinConfig              # the dynamics alone (measurement_chain=False)
    control_plant: Any             # keeps the controller's model alive
    n_steps: int                   # logged steps of the run: the trajectory's span at time_step, both ends included


def _effective_inertia(desc: RobotDescription, payload: Payload | None, trajectory: Trajectory,
                       extra: np.ndarray) -> np.ndarray:
    """Smallest inertia a torque on each joint sees along the trajectory: ``min_t 1/[(M(q)+extra)⁻¹]_jj``
    (``extra`` [n, n] kg·m², the reflected rotor inertia)."""
    robot = DrakeRobot(desc, payload)
    times = np.linspace(trajectory.start_time(), trajectory.end_time(), 25)
    inv = [np.diag(np.linalg.inv(robot.mass_matrix(trajectory.value(t).ravel()) + extra)) for t in times]
    return 1.0 / np.max(inv, axis=0)


def _run_length(trajectory: Trajectory, time_step: float) -> int:
    """Steps of a run along ``trajectory``, both ends included."""
    return int(math.floor((trajectory.end_time() - trajectory.start_time()) / time_step + 1e-9)) + 1


def build_twin_diagram(config: TwinConfig, trajectory: Trajectory, measurement_chain: bool = True) -> TwinDiagram:
    """Wire the twin for ``trajectory`` (joint positions vs. time from t = 0; velocity/acceleration by
    differentiation); ``measurement_chain=False``: the dynamics alone, without the sensors and the logger (for
    benchmarks).

    Raises ``ValueError`` when the friction or the elasticity is too stiff for the time step on this trajectory.
    """
    desc, n, dt = config.robot, config.robot.n, config.time_step
    if trajectory.start_time() != 0.0:
        raise TwinConfigError(f"the twin's trajectory must start at t = 0, got {trajectory.start_time()} s "
                              "(Trajectory.shiftRight)")
    link = [e for e in config.effects if e.place == "link"]
    motor, coupling = config.motor, config.motor_coupling
    elastic = next((e for e in config.effects if isinstance(e, Elasticity)), None)
    reflected = reflected_inertia(motor, coupling) if motor is not None else np.zeros((n, n))
    rotor = np.diag(reflected).copy()          # Drake's per-actuator rotor inertia; a coupled rest is the drive's
    if elastic is None:
        check_explicit_friction(friction_slope(link, motor, coupling, desc.effort_limits),
                                _effective_inertia(desc, config.payload, trajectory, reflected), dt)
    else:
        # the spring's implicit damping D acts in parallel with the explicit link friction
        check_explicit_friction(friction_slope(link, max_load=desc.effort_limits) - elastic.damping,
                                _effective_inertia(desc, config.payload, trajectory, np.zeros((n, n))), dt)
        check_elastic_stability(elastic, motor, dt)

    builder = DiagramBuilder()
    plant = builder.AddSystem(robot_plant(desc, config.payload, dt, rotor if elastic is None else None,
                                           None if elastic is None else (elastic.stiffness, elastic.damping)))
    plant.set_name("plant")
    instance = plant.GetModelInstanceByName(desc.name)
    control_plant = robot_plant(desc, config.payload if config.payload_model else None, 0.0, rotor)
    ctrl = AddDiscreteInverseDynamicsController(builder, control_plant, config.kp, config.ki, config.kd, dt)
    coupled = coupling is not None and np.any(reflected != np.diag(rotor))
    drive = AddJointDrive(builder, n, link, motor, elastic, dt, session_time_s=config.session_time_s,
                          drive_offset=np.array(desc.drive.offset) if drive_identified(desc) else None,
                          coupling=coupling,
                          model_plant=robot_plant(desc, config.payload, 0.0, rotor) if coupled else None)
    source = AddTrajectorySource(builder, trajectory)

    state = plant.get_state_output_port(instance)
    builder.Connect(source.GetOutputPort("state"), ctrl.GetInputPort("desired_state"))
    builder.Connect(source.GetOutputPort("qdd"), ctrl.GetInputPort("desired_acceleration"))
    # an elastic joint is position-controlled on the motor side (collocated, see joint_drive.py)
    feedback = drive.GetOutputPort("motor_state") if elastic is not None else state
    builder.Connect(feedback, ctrl.GetInputPort("estimated_state"))
    builder.Connect(ctrl.GetOutputPort("generalized_force"), drive.GetInputPort("motor_torque"))
    builder.Connect(state, drive.GetInputPort("link_state"))
    builder.Connect(drive.GetOutputPort("actuation"), plant.get_actuation_input_port(instance))
    net_actuation = plant.get_net_actuation_output_port(instance)
    if elastic is not None:
        builder.Connect(drive.GetOutputPort("motor_state"), plant.get_desired_state_input_port(instance))
        builder.Connect(net_actuation, drive.GetInputPort("net_actuation"))

    logged = [state, net_actuation]          # q̈ from successive velocities, at block rate (twin_chain.py)
    if elastic is not None:
        logged.append(drive.GetOutputPort("motor_state"))
    n_steps = _run_length(trajectory, dt)
    chain = None
    if measurement_chain:
        chain = AddMeasurementChain(builder, logged, config, drive, n_steps)
    diagram = builder.Build()
    diagram.set_name(f"twin:{config.name}")
    return TwinDiagram(diagram, plant, drive, ctrl, chain, config, control_plant, n_steps)


# ------------------------------------------------------------------------------------------------------------------
# simulation
# ------------------------------------------------------------------------------------------------------------------
def _check_trajectory(trajectory: Trajectory, desc: RobotDescription) -> None:
    if trajectory.rows() != desc.n or trajectory.cols() != 1:
        raise TwinConfigError(f"trajectory has shape {trajectory.rows()}x{trajectory.cols()}, robot '{desc.name}' "
                              f"needs {desc.n}x1")
    _, q = sample_positions(trajectory, 1000.0)
    over = np.maximum(q - desc.upper, desc.lower - q)
    if np.any(over > 1e-9):
        i, j = np.unravel_index(np.argmax(over), over.shape)
        raise TwinConfigError(f"trajectory violates the joint limits: joint {j + 1} ({desc.joint_names[j]}) = "
                              f"{math.degrees(q[i, j]):.2f}° at t = {trajectory.start_time() + i / 1000.0:.3f} s, "
                              f"limits [{math.degrees(desc.lower[j]):.1f}°, {math.degrees(desc.upper[j]):.1f}°]")


def start_simulator(twin: TwinDiagram, trajectory: Trajectory) -> Simulator:
    """A Simulator of ``twin`` initialised at the start of ``trajectory``: the plant at its state, the drive in
    equilibrium with it."""
    desc, n = twin.config.robot, twin.config.robot.n
    sim = Simulator(twin.diagram)        # every state is discrete (plant, controller integral, drive): no integrator
    ctx = sim.get_mutable_context()
    pctx = twin.plant.GetMyMutableContextFromRoot(ctx)
    q0 = trajectory.value(0.0).ravel()
    qd0 = trajectory.EvalDerivative(0.0, 1).ravel()
    twin.plant.SetPositions(pctx, q0)
    twin.plant.SetVelocities(pctx, qd0)
    twin.drive.set_motor_state(twin.drive.GetMyMutableContextFromRoot(ctx), q0, qd0,
                               inverse_dynamics(attach_payload(desc, twin.config.payload), q0, qd0, np.zeros(n)))
    sim.Initialize()
    return sim


def simulate_twin(config: TwinConfig, trajectory: Trajectory, payload: Payload | None = None,
                  progress: bool = True, chunk_s: float = 2.0) -> Recording:
    """Simulate the twin along ``trajectory`` and return the Recording its robot logger wrote (see module docstring
    for the channels).

    ``payload`` overrides the config's payload. Raises :class:`TwinConfigError` before simulating when the
    trajectory leaves the joint limits or the friction is too stiff for the time step. The simulation advances in
    ``chunk_s`` pieces (progress bar with the real-time factor), to the end of the block that holds the last step.
    """
    if payload is not None:
        config = config.with_payload(payload)
    desc, n, dt = config.robot, config.robot.n, config.time_step
    _check_trajectory(trajectory, desc)
    if trajectory.start_time() != 0.0:       # the Diagram's clock starts at 0: the session clock keeps the offset
        config = dataclasses.replace(config, session_time_s=config.session_time_s + trajectory.start_time())
        trajectory = trajectory.Clone()
        trajectory.shiftRight(-trajectory.start_time())
    twin = build_twin_diagram(config, trajectory)
    chain = twin.chain
    n_steps = twin.n_steps
    t_end = (run_steps(n_steps, chain.block_steps) + 0.9) * dt     # past the last block's stages (phases < 1.9 steps)

    sim = start_simulator(twin, trajectory)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    span = (n_steps - 1) * dt
    bar = progress_bar(total=round(span, 3), unit="s sim", enabled=progress, desc=f"twin {config.name}",
               bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} s sim [{elapsed}<{remaining}{postfix}]")
    t = 0.0
    while t < t_end:
        t_next = min(t + chunk_s, t_end)
        sim.AdvanceTo(t_next)
        bar.update(round(min(t_next, span) - min(t, span), 3))
        bar.set_postfix_str(f"{min(t_next, span) / max(time.perf_counter() - wall0, 1e-9):.1f}x real time")
        t = t_next
    bar.close()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    logged = chain.clock.carry(chain.clock.GetMyContextFromRoot(sim.get_context()), 4)
    return _to_recording(config, chain, LoggerCarry.from_vector(logged, n, config.logger), span, wall, cpu)


def _to_recording(config: TwinConfig, chain: MeasurementChain, logger: LoggerCarry, span_s: float, wall_s: float,
                  cpu_s: float) -> Recording:
    """The Recording of the rows the chain's robot logger wrote (``logger``: its state at the run's end)."""
    rows = chain.clock.rows()
    ch = chain.channels.split(rows)
    truth = {k.removeprefix("truth:"): v for k, v in ch.items() if k.startswith("truth:")}
    meta = {**config.meta(), "rate_hz": config.logger.rate_hz, "source": "twin",
            "channels": list(config.logger.channels), "samples_lost": int(logger.seen) - rows.shape[0],
            "sim_wall_s": round(wall_s, 3), "sim_cpu_s": round(cpu_s, 3),
            "real_time_factor": round(span_s / max(wall_s, 1e-9), 2)}
    return Recording(t=ch["t"], q=ch["q"], tau=ch["tau"], qd=ch.get("qd"), f_ext=ch["f_ext"], truth=truth,
                     meta=json.loads(json.dumps(meta)))


# ------------------------------------------------------------------------------------------------------------------
# the Fig. 2.5 experiment and the demo
# ------------------------------------------------------------------------------------------------------------------
def hysteresis_test_trajectory(desc: RobotDescription, amplitude_deg: float = 10.0, speed_fraction: float = 0.1,
                               cycles: int = 2, blend_s: float = 0.3, pause_s: float = 0.5
                               ) -> tuple[PiecewisePolynomial, list[tuple[int, float, float]]]:
    """Joint-wise triangular motion ±amplitude around the zero pose at ``speed_fraction`` of each joint's velocity
    limit (thesis Fig. 2.5), one joint after the other.

    The velocity is constant except at the vertices, where it reverses linearly within ``blend_s``: a triangle
    convolved with a ``blend_s`` box, its corners raised by ``v·blend_s/4`` so that the peaks reach ±amplitude.
    Returns the trajectory (cubic Hermite through 10 ms knots) and, per joint, ``(joint, t_start, t_end)``.
    """
    from scipy.ndimage import uniform_filter1d

    times, points, windows = [0.0], [np.zeros(desc.n)], []
    t = pause_s
    for j in range(desc.n):
        speed = speed_fraction * desc.velocity_limits[j]
        amp = math.radians(amplitude_deg) + speed * blend_s / 4.0
        leg = amp / speed
        start = t
        times.append(t)
        points.append(np.zeros(desc.n))
        prev = 0.0
        for target in [amp] + [-amp, amp] * cycles + [0.0]:
            t += leg * abs(target - prev) / amp
            q = np.zeros(desc.n)
            q[j] = target
            times.append(t)
            points.append(q)
            prev = target
        windows.append((j, start, t + blend_s))
        t += pause_s
    times.append(t)
    points.append(np.zeros(desc.n))
    corner = PiecewisePolynomial.FirstOrderHold(np.array(times), np.array(points).T)
    fine = 1e-3
    tf = np.arange(0.0, t + fine / 2, fine)
    width = int(round(blend_s / fine)) | 1
    q_smooth = uniform_filter1d(corner.vector_values(tf).T, width, axis=0, mode="nearest")
    qd_smooth = np.gradient(q_smooth, tf, axis=0)
    knots = slice(None, None, 10)
    return PiecewisePolynomial.CubicHermite(tf[knots], q_smooth[knots].T, qd_smooth[knots].T), windows


def run_hysteresis_test(config: TwinConfig, out_dir: str | Path, progress: bool = True) -> tuple[Path, Recording]:
    """Run the Fig. 2.5 experiment on the twin; write ``hysteresis_test.png`` (τ vs. angle per joint, raw +
    Savitzky–Golay overlay) and ``hysteresis_test.npz`` (the Recording) into ``out_dir``."""
    from scipy.signal import savgol_filter

    from proprio.plots.hysteresis import plot_hysteresis_loops
    from proprio.recording import save_recording

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traj, windows = hysteresis_test_trajectory(config.robot)
    rec = simulate_twin(config, traj, progress=progress)
    win = max(5, int(0.25 * rec.rate_hz) | 1)
    loops = []
    for j, ta, tb in windows:
        sel = (rec.t >= ta) & (rec.t <= tb)
        tau = rec.tau[sel, j]
        loops.append((j, np.degrees(rec.q[sel, j]), tau, savgol_filter(tau, win, 2)))
    png = plot_hysteresis_loops(out / "hysteresis_test.png", loops, f"{config.name}: joint-wise triangular motion "
                                "±10° at 10 % speed (cf. thesis Fig. 2.5)")
    save_recording(rec, out / "hysteresis_test.npz")
    return png, rec
