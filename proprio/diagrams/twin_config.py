"""The twin's configuration: :class:`TwinConfig`, its YAML loader and the twin-patch overlay (see
:mod:`proprio.diagrams.twin` for the format)."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from proprio.description import DescriptionError, RobotDescription, load_robot, robot_from_dict
from proprio.effects import Elasticity, JointEffect, Motor, effect_key, make_effects
from proprio.effects.schema import check_effect_block, check_effects_block
from proprio.payload import Payload, PayloadBlock
from proprio.systems.joint_drive import coupling_from_description, motor_from_description
from proprio.robot_log import LoggerConfig
from proprio.typed_yaml import load_typed, per_joint, read_yaml

__all__ = ["TwinConfig", "TwinConfigError", "TwinYaml", "TwinPatchYaml", "ControllerBlock", "PatchFor",
           "load_twin_config", "merge_twin_patch", "PATCH_KEYS"]

PerJoint = float | list[float]
"""One number for every joint, or one per joint (the length is checked against the robot)."""


@dataclass
class ControllerBlock:
    """The ``controller:`` block: inverse-dynamics gains ``kp`` [1/s²], ``ki`` [1/s³], ``kd`` [1/s] and whether the
    controller's model includes the payload."""
    kp: PerJoint = 900.0
    ki: PerJoint = 0.0
    kd: PerJoint = 60.0
    payload_model: bool = False


@dataclass
class TwinYaml:
    """The schema of a twin YAML file (module :mod:`proprio.diagrams.twin` docstring). The ``logger`` block is a
    :class:`~proprio.robot_log.LoggerConfig`, ``payload`` a :class:`~proprio.payload.PayloadBlock`,
    ``drive`` and ``effects`` blocks are checked against the effect classes' declarations
    (:mod:`proprio.effects.schema`) once the robot's joint count is known."""
    robot: str | dict[str, Any]
    name: str | None = None
    time_step: float = 1e-3
    seed: int = 0
    session_time_s: float = 0.0
    logger: dict[str, Any] | None = None
    controller: ControllerBlock | None = None
    drive: dict[str, Any] | None = None
    payload: dict[str, Any] | None = None
    effects: dict[str, Any] | None = None


@dataclass
class PatchFor:
    """The robot a twin patch was fitted for: its description's ``robot`` name and ``joints`` count."""
    robot: str
    joints: int


@dataclass
class TwinPatchYaml:
    """The schema of a twin patch (``twin_patch.yaml``): an overlay on a base twin (module docstring, "Patches")."""
    patch_for: PatchFor
    robot: str | dict[str, Any] | None = None
    effects: dict[str, Any] | None = None
    payload: dict[str, Any] | None = None


PATCH_KEYS = tuple(f.name for f in dataclasses.fields(TwinPatchYaml))
"""The keys a twin patch may hold."""


class TwinConfigError(ValueError):
    """A twin configuration (or its trajectory) is invalid; the message names the field."""


# ------------------------------------------------------------------------------------------------------------------
# configuration
# ------------------------------------------------------------------------------------------------------------------
@dataclass
class TwinConfig:
    """One twin: robot, effects and magnitudes, controller gains, rates, payload and seed (see module docstring).
    ``session_time_s`` [s]: the session clock at the run's t = 0 — time-varying effects (``offset_drift``,
    ``friction_warmup``) see ``t + session_time_s``, and the Recording carries it in ``meta["session_time_s"]``.
    ``motor_coupling``: the normalised coupling ``C [n, n]`` of the robot's coupled drive block when the motor side
    comes from it (no twin ``drive`` block), else ``None`` (:mod:`proprio.systems.joint_drive`)."""
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
    motor_coupling: np.ndarray | None = None

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "<dict>", base_link: str | None = None,
                  tip_link: str | None = None) -> "TwinConfig":
        """Load the mapping of a twin YAML (``source`` names it in errors): first its shape, strictly
        (:class:`TwinYaml`: an unknown key names the nearest valid one), then the physics checks. ``base_link``/
        ``tip_link`` select the chain of a URDF ``robot`` (:func:`~proprio.description.load_robot`)."""
        if not isinstance(data, dict):
            raise TwinConfigError(f"{source}: a twin config must be a YAML mapping")
        spec = load_typed(TwinYaml, data, source, TwinConfigError)
        desc = _robot_of(spec.robot, f"{source}: robot", base_link, tip_link)
        n = desc.n
        try:
            effects = make_effects(spec.effects, n, f"{source}: effects", TwinConfigError)
        except TwinConfigError:
            raise
        except ValueError as exc:                            # a range the effect class refuses
            raise TwinConfigError(f"{source}: effects: {exc}") from exc
        ctrl = spec.controller or ControllerBlock()
        gains = {}
        for key in ("kp", "ki", "kd"):
            g = np.asarray(per_joint(getattr(ctrl, key), n, f"{source}: controller.{key}", TwinConfigError))
            if np.any(g < 0) or not np.all(np.isfinite(g)):
                raise TwinConfigError(f"{source}: controller.{key} must be >= 0, a number or {n} numbers")
            gains[key] = g
        session_time_s = spec.session_time_s
        if not (math.isfinite(session_time_s) and session_time_s >= 0):
            raise TwinConfigError(f"{source}: session_time_s must be a finite number of seconds >= 0, got "
                                  f"{session_time_s}")
        time_step = spec.time_step
        if not time_step > 0:
            raise TwinConfigError(f"{source}: time_step must be > 0 s, got {time_step}")
        try:
            logger = LoggerConfig.from_dict(spec.logger, time_step, f"{source}: logger")
        except ValueError as exc:
            raise TwinConfigError(str(exc)) from exc
        if spec.drive is not None:
            check_effect_block(Motor, spec.drive, n, f"{source}: drive", TwinConfigError)
        try:
            motor = Motor.from_config(spec.drive, n) if spec.drive is not None else motor_from_description(desc)
        except ValueError as exc:
            raise TwinConfigError(f"{source}: drive: {exc}") from exc
        coupling = coupling_from_description(desc) if spec.drive is None else None
        if coupling is not None and any(isinstance(e, Elasticity) for e in effects):
            raise TwinConfigError(f"{source}: effects.elasticity: the robot's drive is coupled (drive.coupling), the "
                                  "twin simulates coupled drives rigid only; give the twin config its own 'drive' "
                                  "block")
        if any(isinstance(e, Elasticity) for e in effects) and (motor is None or np.any(motor.motor_inertia <= 0)):
            raise TwinConfigError(f"{source}: effects.elasticity needs a 'drive' block with motor_inertia > 0 on every "
                                  "joint (the motor-side state)")
        try:
            payload = Payload.from_dict(spec.payload, f"{source}: payload")
        except ValueError as exc:
            raise TwinConfigError(str(exc) if str(exc).startswith(source) else f"{source}: payload: {exc}") from exc
        return cls(robot=desc, effects=effects, payload_model=ctrl.payload_model, motor=motor, payload=payload,
                   time_step=time_step, logger=logger, seed=spec.seed, name=spec.name or Path(source).stem,
                   raw=data, session_time_s=session_time_s, motor_coupling=coupling, **gains)

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
                "drive": None if self.motor is None else {
                    **{k: v.tolist() for k, v in self.motor.params().items()},
                    **({} if self.motor_coupling is None else {"coupling": self.motor_coupling.tolist()})},
                "payload": None if self.payload is None else dataclasses.asdict(self.payload), "seed": self.seed,
                "logger": self.logger.to_dict(), "session_time_s": self.session_time_s}


def _robot_of(value: Any, where: str, base_link: str | None = None, tip_link: str | None = None
              ) -> RobotDescription:
    """The robot of a ``robot:`` entry: a built-in name, a file/directory path or a ``proprio-robot/v1`` mapping
    (``base_link``/``tip_link``: the chain of a URDF file)."""
    if isinstance(value, dict) and (base_link is not None or tip_link is not None):
        raise TwinConfigError(f"{where}: base/tip links select the chain of a URDF file, the robot is a mapping")
    try:
        return robot_from_dict(value, where) if isinstance(value, dict) else load_robot(value, base_link, tip_link)
    except (DescriptionError, FileNotFoundError, KeyError, TypeError, ValueError) as exc:
        raise TwinConfigError(f"{where}: cannot load robot ({exc})") from exc


def merge_twin_patch(base: dict[str, Any], patch: dict[str, Any], source: str = "<patch>",
                     base_dir: str | Path | None = None, base_link: str | None = None,
                     tip_link: str | None = None) -> dict[str, Any]:
    """The twin-config mapping ``base`` with ``patch`` merged in (module docstring, "Patches").

    ``patch_for`` must name the base's robot (its description's ``name``) and joint count; the patch's effects are
    added to the base's (an effect the base already has is an error: the patch was fitted against a model without
    it); its payload needs a base without one; its ``robot`` replaces the base's robot when it has the same joints.
    A relative ``robot`` path is taken relative to ``base_dir`` (the patch's folder) when the file is there.
    ``base_link``/``tip_link`` select the chain of the base's URDF robot. Raises :class:`TwinConfigError` naming the
    offending field."""
    if not isinstance(patch, dict):
        raise TwinConfigError(f"{source}: a twin patch must be a YAML mapping")
    if not isinstance(base, dict):
        raise TwinConfigError("base twin: a twin config must be a YAML mapping")
    spec = load_typed(TwinPatchYaml, patch, source, TwinConfigError)
    base_spec = load_typed(TwinYaml, base, "base twin", TwinConfigError)
    target = spec.patch_for
    desc = _robot_of(base_spec.robot, "base twin: robot", base_link, tip_link)
    if target.robot != desc.name or target.joints != desc.n:
        raise TwinConfigError(f"{source}: patch_for: the patch is for robot '{target.robot}' with "
                              f"{target.joints} joints, the base twin's robot is '{desc.name}' with {desc.n} joints")
    check_effects_block(spec.effects, desc.n, f"{source}: effects", TwinConfigError)
    if spec.payload is not None:
        load_typed(PayloadBlock, spec.payload, f"{source}: payload", TwinConfigError)
    out = {k: v for k, v in base.items()}
    out["name"] = f"{base.get('name', 'twin')}+patch"
    effects = spec.effects or {}
    have = dict(base_spec.effects or {})
    twice = sorted(set(effects) & set(have))
    if twice:
        raise TwinConfigError(f"{source}: effects {twice} are already in the base twin; the patch was fitted against "
                              "a model without them (patch a base twin that lacks them)")
    out["effects"] = {**have, **effects}
    if spec.payload:
        if base_spec.payload:
            raise TwinConfigError(f"{source}: payload: the base twin already has a payload ({base['payload']}); a "
                                  "patch payload is fitted against a model without one")
        out["payload"] = spec.payload
    if spec.robot is not None:
        robot = spec.robot
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
    return read_yaml(text=text, source=source, error=TwinConfigError), source


def load_twin_config(name_or_path: str | Path, patch: str | Path | dict[str, Any] | None = None,
                     base_link: str | None = None, tip_link: str | None = None) -> TwinConfig:
    """Load a twin YAML: a shipped config name (``iiwa14_twin`` or ``iiwa14_twin.yaml``) or a file path; with
    ``patch`` (a twin-patch file or mapping) merged in by :func:`merge_twin_patch`; ``base_link``/``tip_link``
    select the chain of a URDF ``robot``."""
    chain = {"base_link": base_link, "tip_link": tip_link}
    data, source = _read_yaml(name_or_path)
    if patch is None:
        return TwinConfig.from_dict(data, source, **chain)
    if not isinstance(data, dict):
        raise TwinConfigError(f"{source}: a twin config must be a YAML mapping")
    if isinstance(patch, dict):
        merged = merge_twin_patch(data, patch, **chain)
        return TwinConfig.from_dict(merged, f"{source} + patch", **chain)
    path = Path(patch)
    if not path.is_file():
        raise TwinConfigError(f"twin patch '{patch}': no such file")
    pdata, psource = _read_yaml(path, "twin patch")
    merged = merge_twin_patch(data, pdata, psource, path.parent, **chain)
    return TwinConfig.from_dict(merged, f"{source} + {psource}", **chain)
