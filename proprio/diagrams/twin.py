"""The twin: the data-collection diagram that plays the role of the real robot (DESIGN.md, "Physics of the twin").

One Drake Diagram (:func:`build_twin_diagram`, the one :func:`simulate_twin` runs; draw it with
``GetGraphvizString``): ``JointTrajectorySource → InverseDynamicsController → JointDrive (motor side + link friction)
→ MultibodyPlant (discrete 1 ms, payload)``, then the measurement chain ``JointDrive.tau_J → torque_sensor`` (every
sensor-side effect of the effect library and the plugins, :mod:`proprio.systems.sensors`) and ``plant → encoder →
robot_logger`` (rate, lost samples, jittered stamps, the channels the robot reports:
:mod:`proprio.systems.robot_logger`), read block by block from the Diagram's ``record`` output; seeded by
``seed``.
Output: a :class:`~proprio.recording.Recording`
whose measured channels are what that robot logs — stamps ``t``, encoder ``q``, ``tau`` (τ_J) and, only for a robot
that reports one, its own filtered ``qd``; never ``qdd`` — plus the true flange wrench ``f_ext`` (for scoring) and
truth channels:

* ``tau_rbd``: rigid-body torque of the logged motion incl. payload (``proprio.dynamics.inverse_dynamics``);
* ``tau_J_true``: the transmitted, sensed torque before the sensor effects, the torque sensor's input
  (``JointDrive.tau_J`` = ``JointDrive.sensed_torque``: actuation + link friction [− B q̈ for a rigid drive]); it equals
  ``tau_rbd + Σ link friction`` to solver precision (tests: 1e-6 N·m);
* ``tau_<effect>``: each effect's contribution (``tau_viscous_coulomb``, ``tau_hysteresis``, ...);
* ``q_true``, ``qd``, ``qdd``: the plant's exact link position, velocity and acceleration at the true sampling
  instants ``t_true`` (on the clock of ``t``); ``q_motor``, ``qd_motor``: θ, θ̇ of an elastic drive.

Every stage gets q̇, q̈ from the one conditioning path (:mod:`proprio.conditioning`); truth serves scoring only. The
motor side (``drive`` block, ``elasticity``) has no torque channel: it is
hidden behind the sensor and acts only through the motion.

A twin is described by one YAML file (``proprio/configs/iiwa14_twin.yaml``)::

    name: iiwa14_twin
    robot: iiwa14_identified          # built-in name or robot YAML path
    time_step: 0.001                  # s, discrete plant and drive period
    seed: 7
    session_time_s: 0.0               # s, the session clock at the run's t = 0 (time-varying effects see t + it)
    logger: {rate_hz: 1000, channels: [q, tau], stamp_jitter_ms: 0.1, dropout_prob: 0.002}   # see robot_logger
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

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator
from pydrake.systems.controllers import InverseDynamicsController
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, Multiplexer
from pydrake.trajectories import PiecewisePolynomial, Trajectory
from tqdm import tqdm

from proprio.description import RobotDescription
from proprio.dynamics import inverse_dynamics
from proprio.kinematics import flange_pose, point_jacobian
from proprio.payload import Payload, attach_payload
from proprio.plant import drake_robot, robot_plant
from proprio.recording import Recording
from proprio.systems.joint_drive import (
    AddJointDrive, JointDrive, check_elastic_stability, check_explicit_friction, friction_slope,
)
from proprio.identification.regressor import drive_identified
from proprio.effects import Elasticity, EncoderNoise
from proprio.signals import MotionSignals
from proprio.systems.robot_logger import RobotLoggerSystem
from proprio.systems.sensors import AddSampleBank, EncoderSystem, TorqueSensor, TorqueSensorSystem
from proprio.systems.trajectories import AddTrajectorySource, sample_trajectory
from proprio.diagrams.twin_config import (  # noqa: F401  (re-exported: callers import them from here)
    PATCH_KEYS, TwinConfig, TwinConfigError, load_twin_config, merge_twin_patch,
)

__all__ = ["TwinConfig", "TwinConfigError", "load_twin_config", "merge_twin_patch", "PATCH_KEYS", "TwinDiagram",
           "TwinDynamics", "AddTwinDynamics", "build_twin_diagram", "simulate_twin", "payload_wrench",
           "hysteresis_test_trajectory", "run_hysteresis_test"]


# ------------------------------------------------------------------------------------------------------------------
# the diagram
# ------------------------------------------------------------------------------------------------------------------
@dataclass
class TwinDynamics:
    """What :func:`AddTwinDynamics` adds: the discrete plant, the joint drive, the controller (and its model)."""
    plant: MultibodyPlant
    drive: JointDrive
    controller: InverseDynamicsController
    control_plant: MultibodyPlant  # keeps the controller's model alive
    instance: Any                  # the robot's model instance in ``plant``


BLOCK_STEPS = 100
"""Time steps the twin's measurement chain takes in per update (its sample bank; 100 ms at 1 kHz)."""


@dataclass
class TwinDiagram:
    """What :func:`build_twin_diagram` returns: the Diagram and its stages. The Diagram's output port ``record``,
    read at the block times (:meth:`RobotLoggerSystem.block_time`), holds the block of ``BLOCK_STEPS`` time steps
    the chain reads then: per step ``[robot_logger record; torque_sensor record; the bank's sample]`` (``layout``
    names these column slices; see :class:`RobotLoggerSystem`, :class:`TorqueSensorSystem`)."""
    diagram: Diagram
    dynamics: TwinDynamics
    torque_sensor: TorqueSensorSystem
    encoder: EncoderSystem
    robot_logger: RobotLoggerSystem
    layout: dict[str, slice]
    config: TwinConfig
    n_steps: int                   # time steps of the trajectory, both ends included

    @property
    def plant(self) -> MultibodyPlant:
        return self.dynamics.plant

    @property
    def drive(self) -> JointDrive:
        return self.dynamics.drive


def _effective_inertia(desc: RobotDescription, payload: Payload | None, trajectory: Trajectory,
                       extra: np.ndarray) -> np.ndarray:
    """Smallest inertia a torque on each joint sees along the trajectory: ``min_t 1/[(M(q)+diag(extra))⁻¹]_jj``."""
    robot = drake_robot(desc, payload)
    times = np.linspace(trajectory.start_time(), trajectory.end_time(), 25)
    inv = [np.diag(np.linalg.inv(robot.mass_matrix(trajectory.value(t).ravel()) + np.diag(extra))) for t in times]
    return 1.0 / np.max(inv, axis=0)


def AddTwinDynamics(builder: DiagramBuilder, config: TwinConfig, trajectory: Trajectory) -> TwinDynamics:
    """Add the twin's dynamics to ``builder``: ``JointTrajectorySource → InverseDynamicsController → JointDrive →
    MultibodyPlant`` (discrete ``config.time_step``, payload; plants from :func:`proprio.plant.robot_plant`).

    Raises ``ValueError`` when the friction or the elasticity is too stiff for the time step on this trajectory.
    """
    desc, n, dt = config.robot, config.robot.n, config.time_step
    link = [e for e in config.effects if e.place == "link"]
    motor = config.motor
    elastic = next((e for e in config.effects if isinstance(e, Elasticity)), None)
    rotor = motor.motor_inertia if motor is not None else np.zeros(n)
    if elastic is None:
        check_explicit_friction(friction_slope(link, motor),
                                _effective_inertia(desc, config.payload, trajectory, rotor), dt)
    else:
        # the spring's implicit damping D acts in parallel with the explicit link friction
        check_explicit_friction(friction_slope(link) - elastic.damping,
                                _effective_inertia(desc, config.payload, trajectory, np.zeros(n)), dt)
        check_elastic_stability(elastic, motor, dt)

    spring = None if elastic is None else (elastic.stiffness, elastic.damping)
    plant = builder.AddSystem(robot_plant(desc, config.payload, dt, rotor if elastic is None else None, spring))
    plant.set_name("plant")
    instance = plant.GetModelInstanceByName(desc.name)
    control_plant = robot_plant(desc, config.payload if config.payload_model else None, 0.0, rotor)
    ctrl = builder.AddSystem(InverseDynamicsController(control_plant, config.kp, config.ki, config.kd, True))
    ctrl.set_name("controller")
    drive = AddJointDrive(builder, n, link, motor, elastic, dt, session_time_s=config.session_time_s,
                          drive_offset=np.array(desc.drive.offset) if drive_identified(desc) else None)
    source = AddTrajectorySource(builder, trajectory)

    state = plant.get_state_output_port(instance)
    builder.Connect(source.GetOutputPort("state"), ctrl.get_input_port_desired_state())
    builder.Connect(source.GetOutputPort("qdd"), ctrl.get_input_port_desired_acceleration())
    # an elastic joint is position-controlled on the motor side (collocated, see joint_drive.py)
    feedback = drive.GetOutputPort("motor_state") if elastic is not None else state
    builder.Connect(feedback, ctrl.get_input_port_estimated_state())
    builder.Connect(ctrl.get_output_port_generalized_force(), drive.GetInputPort("motor_torque"))
    builder.Connect(state, drive.GetInputPort("link_state"))
    builder.Connect(drive.GetOutputPort("actuation"), plant.get_actuation_input_port(instance))
    builder.Connect(plant.get_net_actuation_output_port(instance), drive.GetInputPort("net_actuation"))
    builder.Connect(plant.get_generalized_acceleration_output_port(instance), drive.GetInputPort("qdd"))
    if elastic is not None:
        builder.Connect(drive.GetOutputPort("motor_state"), plant.get_desired_state_input_port(instance))
    return TwinDynamics(plant, drive, ctrl, control_plant, instance)


def _n_steps(trajectory: Trajectory, time_step: float) -> int:
    return int(math.floor((trajectory.end_time() - trajectory.start_time()) / time_step + 1e-9)) + 1


def build_twin_diagram(config: TwinConfig, trajectory: Trajectory) -> TwinDiagram:
    """Wire the twin for ``trajectory`` (joint positions vs. time; velocity/acceleration by differentiation): the
    dynamics (:func:`AddTwinDynamics`), then the measurement chain on blocks of :data:`BLOCK_STEPS` time steps that a
    C++ shift register keeps (:func:`AddSampleBank`): ``torque_sensor`` (:class:`TorqueSensorSystem`: the drive's τ_J
    law on the plant's net actuation and motion, then every sensor-side effect incl. plugins) and ``encoder``
    (:class:`EncoderSystem`) feed ``robot_logger`` (:class:`RobotLoggerSystem`: rate, lost samples, stamps, the
    robot's own q̇); the Diagram's output ``record`` holds them with the true motion. Seeded by ``config.seed``.

    Raises ``ValueError`` when the friction or the elasticity is too stiff for the time step on this trajectory.
    """
    n, dt, t0, b = config.robot.n, config.time_step, trajectory.start_time(), BLOCK_STEPS
    builder = DiagramBuilder()
    dyn = AddTwinDynamics(builder, config, trajectory)
    plant, drive, instance = dyn.plant, dyn.drive, dyn.instance
    split = builder.AddSystem(Demultiplexer([n, n]))
    split.set_name("link_state")
    builder.Connect(plant.get_state_output_port(instance), split.get_input_port())
    # one time step's row: [net actuation; q; q̇; q̈ (; θ; θ̇)]
    row = [plant.get_net_actuation_output_port(instance), split.get_output_port(0), split.get_output_port(1),
           plant.get_generalized_acceleration_output_port(instance)]
    row += [drive.GetOutputPort("motor_state")] if drive.elasticity is not None else []
    bank, width = AddSampleBank(builder, row, b, dt)
    sensor = builder.AddSystem(TorqueSensorSystem(n, config.effects, dt, b, config.session_time_s, t0, config.seed,
                                                  drive.sensed_torque, (width, 0)))
    sensor.set_name("torque_sensor")
    encoder_effect = next((e for e in config.effects if isinstance(e, EncoderNoise)), None)
    encoder = builder.AddSystem(EncoderSystem(n, encoder_effect, dt, b, t0, config.seed, (width, n)))
    encoder.set_name("encoder")
    n_steps = _n_steps(trajectory, dt)
    logger = builder.AddSystem(RobotLoggerSystem(n, config.logger, dt, n_steps, t0, b, config.seed))
    logger.set_name("robot_logger")
    for port in (sensor.GetInputPort("samples"), encoder.GetInputPort("samples")):
        builder.Connect(bank, port)
    builder.Connect(encoder.GetOutputPort("q_measured"), logger.GetInputPort("q_measured"))
    builder.Connect(sensor.GetOutputPort("tau_measured"), logger.GetInputPort("tau_measured"))

    recorded = [logger.GetOutputPort("record"), sensor.GetOutputPort("record"), bank]
    mux = builder.AddSystem(Multiplexer([port.size() for port in recorded]))
    mux.set_name("record")
    for k, port in enumerate(recorded):
        builder.Connect(port, mux.get_input_port(k))
    builder.ExportOutput(mux.get_output_port(), "record")
    edges = np.cumsum([0] + [port.size() // b for port in recorded])
    layout = {key: slice(int(a), int(b)) for key, a, b in zip(("logger", "sensor", "samples"), edges[:-1], edges[1:])}
    diagram = builder.Build()
    diagram.set_name(f"twin:{config.name}")
    return TwinDiagram(diagram, dyn, sensor, encoder, logger, layout, config, n_steps)


# ------------------------------------------------------------------------------------------------------------------
# simulation
# ------------------------------------------------------------------------------------------------------------------
def _check_trajectory(trajectory: Trajectory, desc: RobotDescription) -> None:
    if trajectory.rows() != desc.n or trajectory.cols() != 1:
        raise TwinConfigError(f"trajectory has shape {trajectory.rows()}x{trajectory.cols()}, robot '{desc.name}' "
                              f"needs {desc.n}x1")
    _, q, _, _ = sample_trajectory(trajectory, 1000.0)
    over = np.maximum(q - desc.upper, desc.lower - q)
    if np.any(over > 1e-9):
        i, j = np.unravel_index(np.argmax(over), over.shape)
        raise TwinConfigError(f"trajectory violates the joint limits: joint {j + 1} ({desc.joint_names[j]}) = "
                              f"{math.degrees(q[i, j]):.2f}° at t = {trajectory.start_time() + i / 1000.0:.3f} s, "
                              f"limits [{math.degrees(desc.lower[j]):.1f}°, {math.degrees(desc.upper[j]):.1f}°]")


def payload_wrench(desc: RobotDescription, payload: Payload | None, q: np.ndarray, qd: np.ndarray,
                   qdd: np.ndarray) -> np.ndarray:
    """True wrench ``[N,6]`` = [f; m] (N, N·m) the payload exerts on the robot at the flange origin, world frame.

    Newton–Euler of the payload body: ``F = m(a_c − g)``, ``N = I α + ω × I ω`` act on the payload, the robot
    receives ``f = −F``, ``m = −(N + (p_c − p_f) × F)``. ``J̇q̇`` from a central difference of the batched
    Jacobian along q̇ (h = 1e-6 s; error ~1e-10). Zero without a payload.
    """
    n_s = q.shape[0]
    if payload is None:
        return np.zeros((n_s, 6))
    com = np.asarray(payload.com_flange, dtype=float)
    h = 1e-6
    jac = point_jacobian(desc, q, com)                                     # [N,6,n] rows [ω; v_c]
    djac = (point_jacobian(desc, q + h * qd, com) - point_jacobian(desc, q - h * qd, com)) / (2 * h)
    acc = np.einsum("sij,sj->si", jac, qdd) + np.einsum("sij,sj->si", djac, qd)   # [α; a_c]
    omega = np.einsum("sij,sj->si", jac[:, :3], qd)
    pose = flange_pose(desc, q)
    rot, p_f = pose[:, :3, :3], pose[:, :3, 3]
    ixx, iyy, izz, ixy, ixz, iyz = payload.inertia
    i_fl = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    i_w = rot @ i_fl @ np.swapaxes(rot, 1, 2)
    force = payload.mass * (acc[:, 3:] - np.asarray(desc.gravity))
    moment = np.einsum("sij,sj->si", i_w, acc[:, :3]) + np.cross(omega, np.einsum("sij,sj->si", i_w, omega))
    p_c = p_f + np.einsum("sij,j->si", rot, com)
    return np.concatenate([-force, -(moment + np.cross(p_c - p_f, force))], axis=1)


def simulate_twin(config: TwinConfig, trajectory: Trajectory, payload: Payload | None = None,
                  progress: bool = True, chunk_s: float = 2.0) -> Recording:
    """Simulate the twin along ``trajectory`` and return the Recording (see module docstring for the channels).

    ``payload`` overrides the config's payload. Raises :class:`TwinConfigError` before simulating when the
    trajectory leaves the joint limits or the friction is too stiff for the time step. The Diagram of
    :func:`build_twin_diagram` runs block by block (progress bar with the real-time factor every ``chunk_s`` of
    simulated time); its random
    draws are seeded with ``config.seed``; only the samples its robot logger took are kept.
    """
    if payload is not None:
        config = config.with_payload(payload)
    desc, n, dt = config.robot, config.robot.n, config.time_step
    _check_trajectory(trajectory, desc)
    twin = build_twin_diagram(config, trajectory)
    t0, n_steps = trajectory.start_time(), twin.n_steps

    sim = Simulator(twin.diagram)
    ctx = sim.get_mutable_context()
    ctx.SetTime(t0)
    pctx = twin.plant.GetMyMutableContextFromRoot(ctx)
    q0 = trajectory.value(t0).ravel()
    qd0 = trajectory.MakeDerivative(1).value(t0).ravel()
    twin.plant.SetPositions(pctx, q0)
    twin.plant.SetVelocities(pctx, qd0)
    twin.drive.set_motor_state(twin.drive.GetMyMutableContextFromRoot(ctx), q0, qd0,
                               inverse_dynamics(attach_payload(desc, config.payload), q0, qd0, np.zeros(n)))
    sim.Initialize()

    chunks = []
    wall0, cpu0 = time.perf_counter(), time.process_time()
    t_end = t0 + (n_steps - 1) * dt
    bar = tqdm(total=round(t_end - t0, 3), unit="s sim", disable=not progress, desc=f"twin {config.name}",
               bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} s sim [{elapsed}<{remaining}{postfix}]")
    record, shown = twin.diagram.GetOutputPort("record"), t0
    for j in range((n_steps - 1) // BLOCK_STEPS + 1):          # read each block of the chain at its block time
        t = twin.robot_logger.block_time(j)
        sim.AdvanceTo(t)
        chunks.append(_rows(record.Eval(ctx), twin.layout))
        if t - shown >= chunk_s or j == (n_steps - 1) // BLOCK_STEPS:
            bar.update(round(min(t, t_end) - shown, 3))
            bar.set_postfix_str(f"{(t - t0) / max(time.perf_counter() - wall0, 1e-9):.1f}x real time")
            shown = min(t, t_end)
    bar.close()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    rows = np.concatenate(chunks)
    if rows.shape[0] != twin.robot_logger.steps.size:
        raise RuntimeError(f"twin logged {rows.shape[0]} of {twin.robot_logger.steps.size} samples")
    return _to_recording(config, twin.layout, rows, wall, cpu)


def _rows(block: np.ndarray, layout: dict[str, slice]) -> np.ndarray:
    """The time steps that were samples, one row each, from one block of the Diagram's ``record`` output."""
    parts, at = [], 0
    for key in ("logger", "sensor", "samples"):
        size = (layout[key].stop - layout[key].start) * BLOCK_STEPS
        parts.append(block[at:at + size].reshape(-1, layout[key].stop - layout[key].start))
        at += size
    rows = np.hstack(parts)
    return rows[rows[:, layout["logger"].start] > 0.5]


def _to_recording(config: TwinConfig, layout: dict[str, slice], rows: np.ndarray, wall_s: float,
                  cpu_s: float) -> Recording:
    """The Recording of the samples the twin's Diagram logged (``rows``: one per sample, columns ``layout``): the
    measured channels its robot logger kept, and the truth channels at the same samples."""
    desc, n = config.robot, config.robot.n
    lg, sens, held = rows[:, layout["logger"]], rows[:, layout["sensor"]], rows[:, layout["samples"]]
    k = lg[:, 1] > 0.5
    lg, sens, held = lg[k], sens[k], held[k]
    stamps, t = lg[:, 2], lg[:, 3]
    q, qd, qdd = held[:, n:2 * n], held[:, 2 * n:3 * n], held[:, 3 * n:4 * n]      # [u; q; q̇; q̈ (; θ; θ̇)]
    truth: dict[str, np.ndarray] = {}
    truth["tau_rbd"] = _in_batches(inverse_dynamics, attach_payload(desc, config.payload), q, qd, qdd)
    # link-side effects act with q̈ = 0, on the session clock (JointDrive.link_torque)
    s_drive = MotionSignals(t=t + config.session_time_s, q=q, qd=qd, qdd=np.zeros_like(qdd))
    for eff in config.effects:
        if eff.place == "link":
            truth[f"tau_{eff.name}"] = eff.torque(s_drive)
    truth["tau_J_true"] = sens[:, n:2 * n]
    names = [e.name for e in config.effects if e.place == "sensor" and not isinstance(e, EncoderNoise)]
    sensor_order = TorqueSensor([e for e in config.effects if e.name in names]).effects
    truth.update({f"tau_{e.name}": sens[:, (2 + i) * n:(3 + i) * n] for i, e in enumerate(sensor_order)})
    truth.update(q_true=q, qd=qd, qdd=qdd, t_true=t - stamps[0])
    if held.shape[1] > 4 * n:                          # elastic drive: θ, θ̇ (what a motor-side sensor reads)
        truth["q_motor"], truth["qd_motor"] = held[:, 4 * n:5 * n], held[:, 5 * n:6 * n]
    f_ext = _in_batches(lambda d, *x: payload_wrench(d, config.payload, *x), desc, q, qd, qdd)
    span = float(rows[-1, layout["logger"].start + 3] - rows[0, layout["logger"].start + 3])
    meta = {**config.meta(), "rate_hz": config.logger.rate_hz, "source": "twin",
            "channels": list(config.logger.channels), "samples_lost": int(rows.shape[0] - lg.shape[0]),
            "sim_wall_s": round(wall_s, 3), "sim_cpu_s": round(cpu_s, 3),
            "real_time_factor": round(span / max(wall_s, 1e-9), 2)}
    qd_robot = lg[:, 4 + 2 * n:4 + 3 * n] if "qd" in config.logger.channels else None
    return Recording(t=stamps - stamps[0], q=lg[:, 4:4 + n], tau=lg[:, 4 + n:4 + 2 * n], qd=qd_robot, f_ext=f_ext,
                     truth=truth, meta=json.loads(json.dumps(meta)))


def _in_batches(fn, desc: RobotDescription, *arrays: np.ndarray, size: int = 100_000) -> np.ndarray:
    """``fn(desc, *arrays)`` over sample batches (the batched kinematics hold ~1 kB per sample in temporaries)."""
    return np.concatenate([fn(desc, *(a[i:i + size] for a in arrays)) for i in range(0, arrays[0].shape[0], size)])


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
