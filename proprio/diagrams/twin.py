"""The twin: the data-collection diagram that plays the role of the real robot (DESIGN.md, "Physics of the twin").

``JointTrajectorySource → DiscreteInverseDynamicsController → drive (motor side + link friction: a C++ FrictionDrive or the
Python JointDrive, proprio.systems.joint_drive) → MultibodyPlant
(discrete 1 ms, payload) → VectorLogSink``; the logged true motion then passes the sensor models
(:mod:`proprio.systems.sensors`) and the robot's logger (:mod:`proprio.systems.robot_logger`: lost samples, jittered
stamps, the channels the robot reports) in one vectorised pass. Output: a :class:`~proprio.recording.Recording`
whose measured channels are what that robot logs — stamps ``t``, encoder ``q``, ``tau`` (τ_J) and, only for a robot
that reports one, its own filtered ``qd``; never ``qdd`` — plus the true flange wrench ``f_ext`` (for scoring) and
truth channels:

* ``tau_rbd``: rigid-body torque of the logged motion incl. payload, the plant's own dynamics in each step
  (``DriveLaw.rigid_body_torque``: net actuation less the rotor inertia the plant carries; equal to
  ``proprio.dynamics.inverse_dynamics`` of the logged motion to 1e-6 N·m, tests);
* ``tau_J_true``: the transmitted, sensed torque before the sensor effects, straight from the simulation
  (``DriveLaw.sensed_torque``: actuation + link friction [− B q̈ for a rigid drive]); it equals
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
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Multiplexer, VectorLogSink
from pydrake.trajectories import PiecewisePolynomial, Trajectory
from tqdm import tqdm

from proprio.description import RobotDescription
from proprio.dynamics import inverse_dynamics
from proprio.kinematics import flange_pose, point_jacobian
from proprio.payload import Payload, attach_payload
from proprio.plant import DrakeRobot, robot_plant
from proprio.recording import Recording
from proprio.systems.joint_drive import (
    AddJointDrive, DriveLaw, check_elastic_stability, check_explicit_friction, friction_slope, reflected_inertia,
)
from proprio.identification.regressor import drive_identified
from proprio.effects import Elasticity, EncoderNoise
from proprio.signals import MotionSignals
from proprio.systems.controller import AddDiscreteInverseDynamicsController, DiscreteInverseDynamicsController
from proprio.systems.robot_logger import RobotLogger
from proprio.systems.sensors import PositionSensor, TorqueSensor
from proprio.systems.trajectories import AddTrajectorySource, sample_trajectory
from proprio.diagrams.twin_config import (  # noqa: F401  (re-exported: callers import them from here)
    PATCH_KEYS, TwinConfig, TwinConfigError, load_twin_config, merge_twin_patch,
)

__all__ = ["TwinConfig", "TwinConfigError", "load_twin_config", "merge_twin_patch", "PATCH_KEYS", "TwinDiagram",
           "build_twin_diagram", "simulate_twin", "payload_wrench", "hysteresis_test_trajectory", "run_hysteresis_test"]


# ------------------------------------------------------------------------------------------------------------------
# the diagram
# ------------------------------------------------------------------------------------------------------------------
@dataclass
class TwinDiagram:
    """What :func:`build_twin_diagram` returns."""
    diagram: Diagram
    plant: Any
    drive: DriveLaw                # FrictionDrive or JointDrive
    controller: DiscreteInverseDynamicsController
    logger: VectorLogSink          # logs [q; q̇; q̈; net actuation (; θ; θ̇ if elastic)] every time_step
    config: TwinConfig
    control_plant: Any             # keeps the controller's model alive


def _effective_inertia(desc: RobotDescription, payload: Payload | None, trajectory: Trajectory,
                       extra: np.ndarray) -> np.ndarray:
    """Smallest inertia a torque on each joint sees along the trajectory: ``min_t 1/[(M(q)+extra)⁻¹]_jj``
    (``extra`` [n, n] kg·m², the reflected rotor inertia)."""
    robot = DrakeRobot(desc, payload)
    times = np.linspace(trajectory.start_time(), trajectory.end_time(), 25)
    inv = [np.diag(np.linalg.inv(robot.mass_matrix(trajectory.value(t).ravel()) + extra)) for t in times]
    return 1.0 / np.max(inv, axis=0)


def build_twin_diagram(config: TwinConfig, trajectory: Trajectory) -> TwinDiagram:
    """Wire the twin for ``trajectory`` (joint positions vs. time; velocity/acceleration by differentiation).

    Raises ``ValueError`` when the friction or the elasticity is too stiff for the time step on this trajectory.
    """
    desc, n, dt = config.robot, config.robot.n, config.time_step
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

    logged = [state, plant.get_generalized_acceleration_output_port(instance), net_actuation]
    if elastic is not None:
        logged.append(drive.GetOutputPort("motor_state"))
    mux = builder.AddSystem(Multiplexer([port.size() for port in logged]))
    for k, port in enumerate(logged):
        builder.Connect(port, mux.get_input_port(k))
    logger = builder.AddSystem(VectorLogSink(mux.get_output_port().size(), dt))
    logger.set_name("logger")
    builder.Connect(mux.get_output_port(), logger.get_input_port())
    diagram = builder.Build()
    diagram.set_name(f"twin:{config.name}")
    return TwinDiagram(diagram, plant, drive, ctrl, logger, config, control_plant)


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


def _log_indices(n_steps: int, time_step: float, rate_hz: float) -> np.ndarray:
    """Indices of the 1/time_step log kept at ``rate_hz`` (nearest step; 150 Hz → 6/7 ms jitter like the iiwa)."""
    if abs(rate_hz * time_step - 1.0) < 1e-9:
        return np.arange(n_steps)
    t_want = np.arange(0.0, n_steps * time_step, 1.0 / rate_hz)
    return np.unique(np.minimum(np.round(t_want / time_step).astype(int), n_steps - 1))


def simulate_twin(config: TwinConfig, trajectory: Trajectory, payload: Payload | None = None,
                  progress: bool = True, chunk_s: float = 2.0) -> Recording:
    """Simulate the twin along ``trajectory`` and return the Recording (see module docstring for the channels).

    ``payload`` overrides the config's payload. Raises :class:`TwinConfigError` before simulating when the
    trajectory leaves the joint limits or the friction is too stiff for the time step. The simulation advances in
    ``chunk_s`` pieces (progress bar with the real-time factor); only the samples at ``logger.rate_hz`` are kept.
    """
    if payload is not None:
        config = config.with_payload(payload)
    desc, n, dt = config.robot, config.robot.n, config.time_step
    _check_trajectory(trajectory, desc)
    twin = build_twin_diagram(config, trajectory)
    t0, t1 = trajectory.start_time(), trajectory.end_time()
    n_steps = int(math.floor((t1 - t0) / dt + 1e-9)) + 1
    keep = _log_indices(n_steps, dt, config.logger.rate_hz)

    sim = Simulator(twin.diagram)        # every state is discrete (plant, controller integral, drive): no integrator
    ctx = sim.get_mutable_context()
    ctx.SetTime(t0)
    pctx = twin.plant.GetMyMutableContextFromRoot(ctx)
    q0 = trajectory.value(t0).ravel()
    qd0 = trajectory.MakeDerivative(1).value(t0).ravel()
    twin.plant.SetPositions(pctx, q0)
    twin.plant.SetVelocities(pctx, qd0)
    twin.drive.set_motor_state(twin.drive.GetMyMutableContextFromRoot(ctx), q0, qd0,
                               inverse_dynamics(attach_payload(desc, config.payload), q0, qd0, np.zeros(n)))
    log = twin.logger.FindMutableLog(ctx)
    sim.Initialize()

    chunks, got = [], 0
    wall0, cpu0 = time.perf_counter(), time.process_time()
    bar = tqdm(total=round(t1 - t0, 3), unit="s sim", disable=not progress, desc=f"twin {config.name}",
               bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} s sim [{elapsed}<{remaining}{postfix}]")
    t = t0
    while got < n_steps:
        t = min(t + chunk_s, t0 + (n_steps - 1) * dt)
        sim.AdvanceTo(t)
        data = log.data().T.copy()
        log.Clear()
        data = data[: n_steps - got]
        idx = keep[(keep >= got) & (keep < got + data.shape[0])] - got
        chunks.append(data[idx])
        got += data.shape[0]
        bar.update(round(data.shape[0] * dt, 3))
        bar.set_postfix_str(f"{(got * dt) / max(time.perf_counter() - wall0, 1e-9):.1f}x real time")
        if t >= t0 + (n_steps - 1) * dt and got < n_steps:
            raise RuntimeError(f"twin logged {got} of {n_steps} samples")
    bar.close()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    data = np.concatenate(chunks)
    return _to_recording(config, twin.drive, t0 + keep * dt, data, wall, cpu)


def _to_recording(config: TwinConfig, drive: DriveLaw, t: np.ndarray, data: np.ndarray, wall_s: float,
                  cpu_s: float) -> Recording:
    """Sensor models, the robot's logger and truth channels from the logged true motion ``[q; q̇; q̈; net actuation
    (; θ; θ̇)]`` at the true instants ``t`` [s]."""
    desc, n = config.robot, config.robot.n
    q, qd, qdd, u = (data[:, k * n:(k + 1) * n] for k in range(4))
    rng = np.random.default_rng(config.seed)
    s = MotionSignals(t=t + config.session_time_s, q=q, qd=qd, qdd=qdd)      # effects see the session clock
    truth: dict[str, np.ndarray] = {}
    truth["tau_rbd"] = drive.rigid_body_torque(u, qdd)
    # link-side effects act with q̈ = 0, on the session clock
    s_drive = MotionSignals(t=t + config.session_time_s, q=q, qd=qd, qdd=np.zeros_like(qdd),
                            tau=drive.transmitted_load(u, t, q, qd, qdd))
    for eff in config.effects:
        if eff.place == "link":
            truth[f"tau_{eff.name}"] = eff.torque(s_drive)
    tau_j = drive.sensed_torque(u, t, q, qd, qdd)
    truth["tau_J_true"] = tau_j
    sensor_effects = [e for e in config.effects if e.place == "sensor" and not isinstance(e, EncoderNoise)]
    tau_meas, parts = TorqueSensor(sensor_effects).measure(s, tau_j, rng)
    truth.update({f"tau_{k}": v for k, v in parts.items()})
    encoder = next((e for e in config.effects if isinstance(e, EncoderNoise)), None)
    q_meas = PositionSensor(encoder).measure(q, rng)
    truth.update(q_true=q, qd=qd, qdd=qdd, t_true=t)
    if data.shape[1] > 4 * n:                          # elastic drive: θ, θ̇ (what a motor-side sensor reads)
        truth["q_motor"], truth["qd_motor"] = data[:, 4 * n:5 * n], data[:, 5 * n:6 * n]
    f_ext = _in_batches(lambda d, *x: payload_wrench(d, config.payload, *x), desc, q, qd, qdd)
    logged = RobotLogger(config.logger).log(t, q_meas, rng)
    k, t0 = logged.keep, float(logged.stamps[0])
    truth = {name: v[k] for name, v in truth.items()}
    truth["t_true"] = truth["t_true"] - t0
    meta = {**config.meta(), "rate_hz": config.logger.rate_hz, "source": "twin",
            "channels": list(config.logger.channels), "samples_lost": int(t.size - k.size),
            "sim_wall_s": round(wall_s, 3), "sim_cpu_s": round(cpu_s, 3),
            "real_time_factor": round(float(t[-1] - t[0]) / max(wall_s, 1e-9), 2)}
    return Recording(t=logged.stamps - t0, q=q_meas[k], tau=tau_meas[k], qd=logged.qd, f_ext=f_ext[k],
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
