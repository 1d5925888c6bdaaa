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

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator
from pydrake.systems.controllers import InverseDynamicsController
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, Multiplexer
from pydrake.trajectories import PiecewisePolynomial, Trajectory
from tqdm import tqdm

from proprio.description import DescriptionError, RobotDescription, load_robot, robot_from_dict
from proprio.dynamics import inverse_dynamics
from proprio.kinematics import flange_pose, point_jacobian
from proprio.payload import Payload, attach_payload
from proprio.plant import drake_robot, robot_plant
from proprio.recording import Recording
from proprio.systems.joint_drive import (
    AddJointDrive, JointDrive, check_elastic_stability, check_explicit_friction, friction_slope,
)
from proprio.effects import Elasticity, EncoderNoise, JointEffect, Motor, effect_key, make_effects
from proprio.signals import MotionSignals
from proprio.systems.robot_logger import LoggerConfig, RobotLoggerSystem
from proprio.systems.sensors import AddSampleBank, EncoderSystem, TorqueSensor, TorqueSensorSystem
from proprio.systems.trajectories import AddTrajectorySource, sample_trajectory

__all__ = ["TwinConfig", "TwinConfigError", "load_twin_config", "merge_twin_patch", "PATCH_KEYS", "TwinDiagram",
           "TwinDynamics", "AddTwinDynamics", "build_twin_diagram", "simulate_twin", "payload_wrench",
           "hysteresis_test_trajectory", "run_hysteresis_test"]

_TOP_KEYS = {"name", "robot", "time_step", "logger", "seed", "controller", "drive", "payload", "effects",
             "session_time_s"}
_CONTROLLER_KEYS = {"kp", "ki", "kd", "payload_model"}
PATCH_KEYS = ("patch_for", "robot", "effects", "payload")


class TwinConfigError(ValueError):
    """A twin configuration (or its trajectory) is invalid; the message names the field."""


# ------------------------------------------------------------------------------------------------------------------
# configuration
# ------------------------------------------------------------------------------------------------------------------
@dataclass
class TwinConfig:
    """One twin: robot, effects and magnitudes, controller gains, rates, payload and seed (see module docstring).
    ``session_time_s`` [s]: the session clock at the run's t = 0 — time-varying effects (``offset_drift``,
    ``friction_warmup``) see ``t + session_time_s``, and the Recording carries it in ``meta["session_time_s"]``."""
    robot: RobotDescription
    effects: list[JointEffect]
    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    payload_model: bool = False
    motor: Motor | None = None
    payload: Payload | None = None
    time_step: float = 1e-3
    logger: LoggerConfig = LoggerConfig()
    seed: int = 0
    name: str = "twin"
    raw: dict[str, Any] = field(default_factory=dict)
    session_time_s: float = 0.0

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "<dict>") -> "TwinConfig":
        if not isinstance(data, dict):
            raise TwinConfigError(f"{source}: a twin config must be a YAML mapping")
        unknown = sorted(set(data) - _TOP_KEYS)
        if unknown:
            raise TwinConfigError(f"{source}: unknown key(s) {unknown}; valid keys: {sorted(_TOP_KEYS)}")
        if "robot" not in data:
            raise TwinConfigError(f"{source}: 'robot' is required (e.g. iiwa14_identified)")
        desc = _robot_of(data["robot"], f"{source}: robot")
        n = desc.n
        try:
            effects = make_effects(data.get("effects") or {}, n)
        except ValueError as exc:
            raise TwinConfigError(f"{source}: effects: {exc}") from exc
        ctrl = data.get("controller") or {}
        bad = sorted(set(ctrl) - _CONTROLLER_KEYS)
        if bad:
            raise TwinConfigError(f"{source}: controller: unknown key(s) {bad}; valid: {sorted(_CONTROLLER_KEYS)}")
        gains = {}
        for key, default in (("kp", 900.0), ("ki", 0.0), ("kd", 60.0)):
            g = np.asarray(ctrl.get(key, default), dtype=float)
            g = np.full(n, float(g)) if g.ndim == 0 else g
            if g.shape != (n,) or np.any(g < 0) or not np.all(np.isfinite(g)):
                raise TwinConfigError(f"{source}: controller.{key} must be >= 0, a number or {n} numbers")
            gains[key] = g
        try:
            session_time_s = float(data.get("session_time_s", 0.0))
        except (TypeError, ValueError) as exc:
            raise TwinConfigError(f"{source}: session_time_s must be a number of seconds, got "
                                  f"{data['session_time_s']!r}") from exc
        if not (math.isfinite(session_time_s) and session_time_s >= 0):
            raise TwinConfigError(f"{source}: session_time_s must be a finite number of seconds >= 0, got "
                                  f"{session_time_s}")
        time_step = float(data.get("time_step", 1e-3))
        if not time_step > 0:
            raise TwinConfigError(f"{source}: time_step must be > 0 s, got {time_step}")
        try:
            logger = LoggerConfig.from_dict(data.get("logger"), time_step, f"{source}: logger")
        except ValueError as exc:
            raise TwinConfigError(str(exc)) from exc
        try:
            motor = Motor.from_config(data["drive"], n) if data.get("drive") is not None else None
        except ValueError as exc:
            raise TwinConfigError(f"{source}: drive: {exc}") from exc
        if any(isinstance(e, Elasticity) for e in effects) and (motor is None or np.any(motor.motor_inertia <= 0)):
            raise TwinConfigError(f"{source}: effects.elasticity needs a 'drive' block with motor_inertia > 0 on every "
                                  "joint (the motor-side state)")
        try:
            payload = Payload.from_dict(data.get("payload"))
        except (ValueError, KeyError, TypeError) as exc:
            raise TwinConfigError(f"{source}: payload: {exc}") from exc
        return cls(robot=desc, effects=effects, payload_model=bool(ctrl.get("payload_model", False)),
                   motor=motor, payload=payload, time_step=time_step, logger=logger, seed=int(data.get("seed", 0)),
                   name=str(data.get("name", Path(source).stem)), raw=data, session_time_s=session_time_s, **gains)

    def effect(self, name: str) -> JointEffect | None:
        return next((e for e in self.effects if e.name == name), None)

    def with_payload(self, payload: Payload | None) -> "TwinConfig":
        return dataclasses.replace(self, payload=payload)

    def with_effects(self, effects: list[JointEffect]) -> "TwinConfig":
        return dataclasses.replace(self, effects=list(effects))

    def with_session_time(self, session_time_s: float) -> "TwinConfig":
        """The same twin with its session clock starting at ``session_time_s`` [s] (>= 0)."""
        if not (math.isfinite(session_time_s) and session_time_s >= 0):
            raise TwinConfigError(f"session_time_s must be a finite number of seconds >= 0, got {session_time_s}")
        return dataclasses.replace(self, session_time_s=float(session_time_s))

    def with_logger(self, **changes: Any) -> "TwinConfig":
        """The same twin with ``logger`` fields changed (e.g. ``rate_hz=150``), checked like the YAML."""
        try:
            logger = dataclasses.replace(self.logger, **changes)
            logger.check(self.time_step)
        except (TypeError, ValueError) as exc:
            raise TwinConfigError(f"logger: {exc}") from exc
        return dataclasses.replace(self, logger=logger)

    def meta(self) -> dict[str, Any]:
        """JSON-able description for ``Recording.meta``."""
        return {"twin": self.name, "robot": self.robot.name, "robot_description": self.robot.to_dict(),
                "time_step": self.time_step,
                "effects": {effect_key(e): {k: v.tolist() for k, v in e.params().items()} for e in self.effects},
                "controller": {"kp": self.kp.tolist(), "ki": self.ki.tolist(), "kd": self.kd.tolist(),
                               "payload_model": self.payload_model},
                "drive": None if self.motor is None else {k: v.tolist() for k, v in self.motor.params().items()},
                "payload": None if self.payload is None else dataclasses.asdict(self.payload), "seed": self.seed,
                "logger": self.logger.to_dict(), "session_time_s": self.session_time_s}


def _robot_of(value: Any, where: str) -> RobotDescription:
    """The robot of a ``robot:`` entry: a built-in name, a file/directory path or a ``proprio-robot/v1`` mapping."""
    try:
        return robot_from_dict(value, where) if isinstance(value, dict) else load_robot(value)
    except (DescriptionError, FileNotFoundError, KeyError, TypeError, ValueError) as exc:
        raise TwinConfigError(f"{where}: cannot load robot ({exc})") from exc


def merge_twin_patch(base: dict[str, Any], patch: dict[str, Any], source: str = "<patch>",
                     base_dir: str | Path | None = None) -> dict[str, Any]:
    """The twin-config mapping ``base`` with ``patch`` merged in (module docstring, "Patches").

    ``patch_for`` must name the base's robot (its description's ``name``) and joint count; the patch's effects are
    added to the base's (an effect the base already has is an error: the patch was fitted against a model without
    it); its payload needs a base without one; its ``robot`` replaces the base's robot when it has the same joints.
    A relative ``robot`` path is taken relative to ``base_dir`` (the patch's folder) when the file is there. Raises
    :class:`TwinConfigError` naming the offending field."""
    if not isinstance(patch, dict):
        raise TwinConfigError(f"{source}: a twin patch must be a YAML mapping")
    unknown = sorted(set(patch) - set(PATCH_KEYS))
    if unknown:
        raise TwinConfigError(f"{source}: unknown key(s) {unknown}; a twin patch may hold {list(PATCH_KEYS)}")
    target = patch.get("patch_for")
    if not isinstance(target, dict) or not {"robot", "joints"} <= set(target):
        raise TwinConfigError(f"{source}: patch_for must be a mapping {{robot: <name>, joints: <n>}} (the robot the "
                              "patch was fitted for)")
    if "robot" not in base:
        raise TwinConfigError("base twin: 'robot' is required")
    desc = _robot_of(base["robot"], "base twin: robot")
    if str(target["robot"]) != desc.name or int(target["joints"]) != desc.n:
        raise TwinConfigError(f"{source}: patch_for: the patch is for robot '{target['robot']}' with "
                              f"{target['joints']} joints, the base twin's robot is '{desc.name}' with {desc.n} joints")
    out = {k: v for k, v in base.items()}
    out["name"] = f"{base.get('name', 'twin')}+patch"
    effects = patch.get("effects") or {}
    if not isinstance(effects, dict):
        raise TwinConfigError(f"{source}: effects must be a mapping {{name: parameters}}")
    have = dict(base.get("effects") or {})
    twice = sorted(set(effects) & set(have))
    if twice:
        raise TwinConfigError(f"{source}: effects {twice} are already in the base twin; the patch was fitted against "
                              "a model without them (patch a base twin that lacks them)")
    out["effects"] = {**have, **effects}
    if patch.get("payload"):
        if base.get("payload"):
            raise TwinConfigError(f"{source}: payload: the base twin already has a payload ({base['payload']}); a "
                                  "patch payload is fitted against a model without one")
        out["payload"] = patch["payload"]
    if patch.get("robot") is not None:
        robot = patch["robot"]
        if isinstance(robot, str) and base_dir is not None and not Path(robot).is_absolute() \
                and (Path(base_dir) / robot).exists():
            robot = str(Path(base_dir) / robot)
        new = _robot_of(robot, f"{source}: robot")
        if new.joint_names != desc.joint_names:
            raise TwinConfigError(f"{source}: robot: its joints {new.joint_names} differ from the base robot's "
                                  f"{desc.joint_names}")
        out["robot"] = robot
    return out


def _read_yaml(name_or_path: str | Path, what: str = "twin config") -> tuple[Any, str]:
    """``(mapping, source)`` of a YAML file or a shipped config name."""
    path = Path(name_or_path)
    if path.exists():
        text, source = path.read_text(), str(path)
    else:
        stem = path.name if path.suffix in (".yaml", ".yml") else f"{path.name}.yaml"
        res = resources.files("proprio.configs").joinpath(stem)
        if not res.is_file():
            shipped = sorted(p.name for p in resources.files("proprio.configs").iterdir()
                             if p.name.endswith("twin.yaml"))
            raise TwinConfigError(f"{what} '{name_or_path}' is neither a file nor a shipped config {shipped}")
        text, source = res.read_text(), stem
    try:
        return yaml.safe_load(text), source
    except yaml.YAMLError as exc:
        raise TwinConfigError(f"{source}: not valid YAML ({exc})") from exc


def load_twin_config(name_or_path: str | Path, patch: str | Path | dict[str, Any] | None = None) -> TwinConfig:
    """Load a twin YAML: a shipped config name (``iiwa14_twin`` or ``iiwa14_twin.yaml``) or a file path; with
    ``patch`` (a twin-patch file or mapping) merged in by :func:`merge_twin_patch`."""
    data, source = _read_yaml(name_or_path)
    if patch is None:
        return TwinConfig.from_dict(data, source)
    if not isinstance(data, dict):
        raise TwinConfigError(f"{source}: a twin config must be a YAML mapping")
    if isinstance(patch, dict):
        merged = merge_twin_patch(data, patch)
        return TwinConfig.from_dict(merged, f"{source} + patch")
    path = Path(patch)
    if not path.is_file():
        raise TwinConfigError(f"twin patch '{patch}': no such file")
    pdata, psource = _read_yaml(path, "twin patch")
    merged = merge_twin_patch(data, pdata, psource, path.parent)
    return TwinConfig.from_dict(merged, f"{source} + {psource}")


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
    drive = AddJointDrive(builder, n, link, motor, elastic, dt, session_time_s=config.session_time_s)
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
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.signal import savgol_filter

    from proprio.io import save_figure
    from proprio.recording import save_recording

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    traj, windows = hysteresis_test_trajectory(config.robot)
    rec = simulate_twin(config, traj, progress=progress)
    fig, axes = plt.subplots(2, 4, figsize=(16, 7.5))
    for (j, ta, tb), ax in zip(windows, axes.ravel()):
        sel = (rec.t >= ta) & (rec.t <= tb)
        ang, tau = np.degrees(rec.q[sel, j]), rec.tau[sel, j]
        win = max(5, int(0.25 * rec.rate_hz) | 1)
        ax.plot(ang, tau, lw=0.4, color="0.6", label="measured τ_J")
        ax.plot(ang, savgol_filter(tau, win, 2), lw=1.6, color="C3", label="Savitzky–Golay")
        ax.set_title(f"joint {j + 1}")
        ax.set_xlabel("angle [°]")
        ax.set_ylabel("τ [N·m]")
    axes.ravel()[-1].axis("off")
    axes.ravel()[0].legend(loc="best", fontsize=8)
    fig.suptitle(f"{config.name}: joint-wise triangular motion ±10° at 10 % speed (cf. thesis Fig. 2.5)")
    fig.tight_layout()
    png = save_figure(fig, out / "hysteresis_test.png")
    save_recording(rec, out / "hysteresis_test.npz")
    return png, rec
