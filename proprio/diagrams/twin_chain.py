"""The twin's measurement chain inside its Diagram: the log sampler, the transmitted torque, the torque sensor, the
encoder and the robot's logger, as block-rate Systems behind a compiled shift register.

The plant's logged signals ``[q; q̇]``, ``net actuation`` (, ``[θ; θ̇]``) enter a
:class:`~proprio.systems.blocks.BlockRegister` (Drake primitives only at the 1 kHz step: chunks of 100 steps; its
``Selector`` joins the ports); the ``block_clock`` (:class:`~proprio.systems.blocks.BlockClock`, the chain's one
Python System with events) gathers the chunks into blocks of ``B`` = 1 000 steps and, at a fractional phase of the
step after each block, has five stateless :class:`~proprio.systems.blocks.BlockStage` s apply the laws of the
layers below in order:

1. ``log_sampler`` — the steps the robot logs (:func:`proprio.robot_log.logged_steps`), their instants and the
   motion with q̈ = (q̇ₖ₊₁ − q̇ₖ)/Δt (the next velocity of the block's last step from the sample of the step after
   it, which the register's level 0 holds when the clock takes the block): the discrete plant's acceleration port
   computes exactly this, so q̈ is not registered;
2. ``transmission`` — the truth of the motion: τ_RBD and the link-side effects' torques (reversal state carried,
   :class:`~proprio.effects.sensor_chain.PathEffects`), the transmitted τ_J (``DriveLaw.sensed_torque``) and the
   payload's flange wrench (:func:`payload_wrench`);
3. ``torque_sensor`` — :class:`~proprio.effects.sensor_chain.TorqueSensor` (path state and noise streams carried);
4. ``encoder`` — :class:`~proprio.effects.sensor_chain.PositionSensor`;
5. ``robot_logger`` — :class:`~proprio.robot_log.RobotLogger` (losses, stamps, the robot's q̇); it writes the log rows
   (:attr:`TwinChannels.names`), which are the twin's Recording.

Each stage's state between blocks (reversal and Dahl state, the random streams' states, the logger's open bursts
and filter) is numeric discrete state of the clock. The run is simulated to the end of the block that holds its last
step (:func:`run_steps`): the last block is flushed through the same Systems.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from pydrake.systems.framework import DiagramBuilder, OutputPort

from proprio.description import RobotDescription
from proprio.effects import EncoderNoise
from proprio.effects.sensor_chain import PathEffects, PositionSensor, TorqueSensor
from proprio.kinematics import flange_pose, point_jacobian
from proprio.payload import Payload
from proprio.robot_log import LoggerCarry, RobotLogger, logged_steps
from proprio.signals import MotionSignals
from proprio.systems.blocks import AddBlockRegister, BlockClock, BlockRegister, BlockStage, stage_block
from proprio.systems.joint_drive import DriveLaw

__all__ = ["TwinChannels", "MeasurementChain", "AddMeasurementChain", "run_steps", "payload_wrench",
           "REGISTER_LEVELS", "BLOCK_CHUNKS"]

REGISTER_LEVELS = (10, 10)
"""Chunks per level of the twin's shift register: chunks of 100 steps."""
BLOCK_CHUNKS = 10
"""Chunks per block: the laws run on blocks of 1 000 steps (per-joint Python loops at block rate need blocks of
≥ 500 samples to stay cheap)."""


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


@dataclass(frozen=True)
class TwinChannels:
    """The columns of the robot logger's rows: ``names`` and ``widths`` in order (``t``, ``q``, ``tau``, ``qd`` if
    reported, ``f_ext``, then the truth channels)."""
    names: tuple[str, ...]
    widths: tuple[int, ...]

    @property
    def width(self) -> int:
        return sum(self.widths)

    def split(self, rows: np.ndarray) -> dict[str, np.ndarray]:
        """The named channels of ``rows [M, width]`` (1-wide ones as ``[M]``)."""
        out, c = {}, 0
        for name, w in zip(self.names, self.widths):
            out[name] = rows[:, c] if w == 1 else rows[:, c:c + w]
            c += w
        return out


@dataclass
class MeasurementChain:
    """What :func:`AddMeasurementChain` added: the register, the five stages and their clock (whose ``log`` holds the
    logger's rows), the logger's ``channels``."""
    register: BlockRegister
    sampler: BlockStage
    transmission: BlockStage
    sensor: BlockStage
    encoder: BlockStage
    logger: BlockStage
    clock: BlockClock
    channels: TwinChannels
    block_steps: int


def run_steps(n_steps: int, block_steps: int) -> int:
    """Steps to simulate for a run of ``n_steps`` logged steps: to the end of the block holding the last one."""
    return -(-n_steps // block_steps) * block_steps


def AddMeasurementChain(builder: DiagramBuilder, signals: Sequence[OutputPort], config, drive: DriveLaw,
                        n_steps: int, levels: tuple[int, ...] = REGISTER_LEVELS,
                        chunks: int = BLOCK_CHUNKS) -> MeasurementChain:
    """Add the measurement chain (module docstring) of the twin ``config`` (a
    :class:`~proprio.diagrams.twin_config.TwinConfig`) for a run of ``n_steps`` steps from time 0, fed by
    ``signals`` = the ports ``[q; q̇]``, ``net actuation`` (, ``[θ; θ̇]``), the plant's at its own instants, which
    the register joins into its samples, and the ``drive``'s law."""
    desc, n, dt = config.robot, config.robot.n, config.time_step
    registered = sum(port.size() for port in signals)     # [q; q̇; net actuation (; θ; θ̇)]
    width = registered + n                           # the rows' motion with q̈: [q; q̇; q̈; net actuation (; θ; θ̇)]
    elastic = width > 4 * n
    if len(levels) < 2:
        raise ValueError(f"AddMeasurementChain: levels must have at least two levels, got {levels}")
    register = AddBlockRegister(builder, [p.size() for p in signals], dt, levels)
    for port, sample_in in zip(signals, register.samples):
        builder.Connect(port, sample_in)
    B = register.size * chunks
    # the clock reads a block once the register holds it, after the instant of the step that follows it (so that
    # level 0 holds that step's sample, whose q̇ gives q̈ of the block's last step) and before the next chunk's
    phase = max(1.0, register.phase) + 0.1
    session = config.session_time_s

    # 1. the steps the robot logs, and their instants
    def sample(inputs: list[np.ndarray], carry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo = int(carry[0]) * B
        idx = logged_steps(lo, lo + B, n_steps, dt, config.logger.rate_hz)
        block = inputs[0].reshape(B, registered)
        # q̈ of the discrete plant: (v_{k+1} − v_k)/Δt, Drake's own expression (its acceleration port), exactly
        after = inputs[1][-registered:]                                          # step lo + B: level 0's newest
        v = np.concatenate([block[:, n:2 * n], after[None, n:2 * n]])          # v_{lo..lo+B}
        qdd = (v[1:] - v[:-1]) / dt
        rows = np.column_stack([idx * dt, block[idx - lo, :2 * n], qdd[idx - lo], block[idx - lo, 2 * n:]])
        return rows, lo + B >= n_steps, carry + 1.0

    def motion(v: np.ndarray) -> tuple[np.ndarray, ...]:
        rows, final = stage_block(v, sampler)
        return (rows[:, 0], *(rows[:, 1 + k * n:1 + (k + 1) * n] for k in range(width // n)), final)

    # 2. the truth of the motion: τ_RBD, link-side effects, transmitted τ_J, payload wrench
    link = [e for e in config.effects if e.place == "link"]
    link_path = PathEffects(link, n)

    def transmit(inputs: list[np.ndarray], carry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t, q, qd, qdd, u, *_, final = motion(inputs[0])
        if t.size == 0:
            return np.zeros((0, tw)), final, carry
        # link-side effects act with q̈ = 0; a load-dependent friction on the torque its gear transmitted
        s_drive = MotionSignals(t + session, q, qd, np.zeros_like(qdd), drive.transmitted_load(u, t, q, qd, qdd))
        piece = link_path.begin(s_drive, carry)
        parts = [piece.torque(eff, s_drive) for eff in link]
        tau_link = np.zeros_like(qd)
        for p in parts:
            tau_link = tau_link + p
        tau_j = drive.sensed_torque(u, t, q, qd, qdd, tau_link=tau_link)
        rows = np.column_stack([tau_j, drive.rigid_body_torque(u, qdd), *parts,
                                payload_wrench(desc, config.payload, q, qd, qdd)])
        return rows, final, piece.end()

    # 3. the torque sensor; 4. the encoder
    sensor_effects = [e for e in config.effects if e.place == "sensor" and not isinstance(e, EncoderNoise)]
    torque_sensor = TorqueSensor(sensor_effects, n, config.seed)
    encoder_effect = next((e for e in config.effects if isinstance(e, EncoderNoise)), None)
    position_sensor = PositionSensor(encoder_effect, n, config.seed)
    tw = (2 + len(link)) * n + 6

    def sense(inputs: list[np.ndarray], carry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t, q, qd, qdd, *_, final = motion(inputs[0])
        if t.size == 0:
            return np.zeros((0, (1 + len(torque_sensor.order)) * n)), final, carry
        tau_j = stage_block(inputs[1], transmission)[0][:, :n]
        tau, parts, carry = torque_sensor.measure(MotionSignals(t + session, q, qd, qdd), tau_j, carry)
        return np.column_stack([tau, *parts.values()]), final, carry

    def encode(inputs: list[np.ndarray], carry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        _, q, *_, final = motion(inputs[0])
        q_meas, carry = position_sensor.measure(q, carry)
        return q_meas, final, carry

    # 5. the robot's logger
    logger = RobotLogger(config.logger, n, config.seed)
    reports_qd = "qd" in config.logger.channels
    measured = ["t", "q", "tau"] + (["qd"] if reports_qd else []) + ["f_ext"]
    truth = ["tau_rbd"] + [f"tau_{e.name}" for e in link] + ["tau_J_true"] + \
        [f"tau_{e.name}" for e in torque_sensor.order] + ["q_true", "qd", "qdd", "t_true"] + \
        (["q_motor", "qd_motor"] if elastic else [])
    names = measured + [f"truth:{k}" for k in truth]
    widths = [1, n, n] + ([n] if reports_qd else []) + [6] + [n] * (len(truth) - 1 - 2 * elastic) + [1] + \
        [n] * (2 * elastic)
    channels = TwinChannels(tuple(names), tuple(widths))
    sw = (1 + len(torque_sensor.order)) * n

    def log(inputs: list[np.ndarray], carry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t, q, qd, qdd, _, *motor, final = motion(inputs[0])
        if t.size == 0:
            return np.zeros((0, channels.width)), final, carry
        tr = stage_block(inputs[1], transmission)[0]
        sens = stage_block(inputs[2], sensor)[0]
        q_meas = stage_block(inputs[3], encoder)[0]
        piece, after = logger.log(t, q_meas, LoggerCarry.from_vector(carry, n, config.logger), final)
        k = piece.keep
        torques = np.column_stack([tr[:, n:2 * n], tr[:, 2 * n:-6], tr[:, :n], sens[:, n:]])[k]  # rbd, link, J, sensor
        cols = [piece.stamps, q_meas[k], sens[k, :n]] + ([piece.qd] if reports_qd else []) + \
            [tr[k, -6:], torques, q[k], qd[k], qdd[k], t[k] - after.stamp0] + [m[k] for m in motor]
        return np.column_stack(cols), final, after.vector()

    def stage(name: str, inputs: dict[str, int], width_k: int, carry0: np.ndarray, law) -> BlockStage:
        return builder.AddNamedSystem(name, BlockStage(inputs, carry0, law, B, width_k))

    chunk = register.block.size()
    sampler = stage("log_sampler", {"held": chunks * chunk, "after": register.recent.size()}, 1 + width,
                    np.zeros(1), sample)
    sampled = sampler.get_output_port().size()
    transmission = stage("transmission", {"samples": sampled}, tw, link_path.start(), transmit)
    transmitted = transmission.get_output_port().size()
    sensor = stage("torque_sensor", {"samples": sampled, "transmission": transmitted}, sw, torque_sensor.start(),
                   sense)
    encoder = stage("encoder", {"samples": sampled}, n, position_sensor.start(), encode)
    robot_logger = stage("robot_logger", {"samples": sampled, "transmission": transmitted,
                                          "torque": sensor.get_output_port().size(),
                                          "position": encoder.get_output_port().size()},
                         channels.width, logger.start().vector(), log)
    stages = [sampler, transmission, sensor, encoder, robot_logger]
    clock = builder.AddNamedSystem("block_clock", BlockClock(stages, chunk, chunks, register.size, dt, phase,
                                                            max_rows=run_steps(n_steps, B),
                                                            after_size=register.recent.size()))
    builder.Connect(register.block, clock.GetInputPort("chunk"))
    builder.Connect(register.recent, clock.GetInputPort("after"))
    builder.Connect(clock.GetOutputPort("held"), sampler.GetInputPort("held"))
    builder.Connect(clock.GetOutputPort("after"), sampler.GetInputPort("after"))
    for system in (transmission, sensor, encoder, robot_logger):
        builder.Connect(sampler.GetOutputPort("out"), system.GetInputPort("samples"))
    builder.Connect(transmission.GetOutputPort("out"), sensor.GetInputPort("transmission"))
    builder.Connect(transmission.GetOutputPort("out"), robot_logger.GetInputPort("transmission"))
    builder.Connect(sensor.GetOutputPort("out"), robot_logger.GetInputPort("torque"))
    builder.Connect(encoder.GetOutputPort("out"), robot_logger.GetInputPort("position"))
    for k, system in enumerate(stages):
        builder.Connect(clock.GetOutputPort(f"carry_{k}"), system.GetInputPort("carry"))
        builder.Connect(system.GetOutputPort("out"), clock.GetInputPort(f"stage_{k}"))
    return MeasurementChain(register, sampler, transmission, sensor, encoder, robot_logger, clock, channels, B)
