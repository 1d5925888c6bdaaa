"""The RFMA config (``proprio/configs/rfma.yaml``, read by :func:`load_rfma_config`): its YAML schema
(:class:`RfmaYaml`, loaded strictly by :mod:`proprio.typed_yaml`: an unknown key names the file, the key path and
the nearest valid key), the run-time :class:`RfmaConfig` (angles in rad) and its checks. The generator is
:mod:`proprio.systems.rfma`."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from proprio.collision import EnvironmentBox
from proprio.typed_yaml import load_typed, read_yaml

__all__ = ["RfmaError", "RfmaConfig", "RfmaYaml", "load_rfma_config"]


class RfmaError(ValueError):
    """A bad RFMA config, or sampling that could not find enough feasible scaffolds."""


@dataclass(frozen=True)
class RfmaConfig:
    """RFMA settings (see ``proprio/configs/rfma.yaml`` for the meaning of each field). Angles in rad here; the
    YAML states degrees where its key ends in ``_deg``."""
    seed: int = 0
    robot: str = "iiwa14_identified"
    scaffolds: int = 150
    joint_margin: float = math.radians(2.0)
    home: tuple[float, ...] = (0.0,) * 7
    return_home: bool = True
    radius: float = 0.8
    x_min: float = 0.0
    z_min: float = 0.0
    boxes: tuple[EnvironmentBox, ...] = ()
    batch: int = 4096
    max_tries: int = 400_000
    terms: int = 3
    amplitude: tuple[float, float] = (math.radians(0.5), math.radians(3.0))
    frequency: tuple[float, float] = (-4.0, 4.0)
    phase: tuple[float, float] = (0.0, 2.0 * math.pi)
    waypoints: tuple[int, int] = (2000, 2500)
    waypoints_per_unit: float = 600.0
    explore_velocity_fraction: tuple[float, float] = (0.1, 0.3)
    explore_acceleration_fraction: float = 0.9
    reach_velocity_fraction: tuple[float, float] = (0.6, 0.9)
    knot_dt: float = 0.02
    check_path: bool = True
    check_step: float = math.radians(1.0)

    def replace(self, **changes: Any) -> "RfmaConfig":
        """A validated copy with some fields changed (e.g. ``scaffolds``, ``seed``)."""
        return _validated(dataclasses.replace(self, **changes))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (radians), stored in trajectory metadata."""
        d = dataclasses.asdict(self)
        d["boxes"] = [dataclasses.asdict(b) for b in self.boxes]
        return d


Interval = tuple[float, float]


@dataclass(frozen=True)
class _Workspace:
    radius_m: float = 0.8
    x_min_m: float = 0.0
    z_min_m: float = 0.0


@dataclass(frozen=True)
class _Box:
    size_m: tuple[float, float, float]
    name: str | None = None
    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class _PathCheck:
    enabled: bool = True
    step_deg: float = 1.0


@dataclass(frozen=True)
class _Sampling:
    batch: int = 4096
    max_tries: int = 400_000


@dataclass(frozen=True)
class _Exploration:
    amplitude_deg: Interval
    frequency: Interval
    phase_rad: Interval
    waypoints: tuple[int, int]
    velocity_fraction: Interval
    terms: int = 3
    waypoints_per_unit: float = 600.0
    acceleration_fraction: float = 0.9


@dataclass(frozen=True)
class _Reach:
    velocity_fraction: Interval


@dataclass(frozen=True)
class RfmaYaml:
    """The schema of an RFMA YAML file (``proprio/configs/rfma.yaml`` documents each key); loaded strictly by
    :func:`proprio.typed_yaml.load_typed` (an unknown key names the nearest valid one)."""
    exploration: _Exploration
    reach: _Reach
    seed: int = 0
    robot: str = "iiwa14_identified"
    scaffolds: int = 150
    joint_margin_deg: float = 2.0
    home_deg: list[float] = field(default_factory=lambda: [0.0] * 7)
    return_home: bool = True
    workspace: _Workspace = _Workspace()
    environment_boxes: list[_Box] | None = None
    path_collision_check: _PathCheck = _PathCheck()
    sampling: _Sampling = _Sampling()
    knot_dt_s: float = 0.02


def _interval(v: tuple[float, float], where: str, lo_min: float | None = None,
              hi_max: float | None = None) -> tuple[float, float]:
    lo, hi = v
    if not lo <= hi:
        raise RfmaError(f"{where}: inverted interval [{lo}, {hi}] (low > high)")
    if lo_min is not None and lo < lo_min:
        raise RfmaError(f"{where}: low bound {lo} is below {lo_min}")
    if hi_max is not None and hi > hi_max:
        raise RfmaError(f"{where}: high bound {hi} exceeds {hi_max}")
    return lo, hi


def _validated(c: RfmaConfig) -> RfmaConfig:
    if c.scaffolds < 1:
        raise RfmaError(f"scaffolds: must be >= 1, got {c.scaffolds}")
    if c.radius <= 0.0:
        raise RfmaError(f"workspace.radius_m: must be > 0, got {c.radius}")
    if c.x_min >= c.radius or c.z_min >= c.radius:
        raise RfmaError(f"workspace: x_min_m={c.x_min}/z_min_m={c.z_min} lie outside the sphere of radius "
                        f"{c.radius} m, no flange position can satisfy them (unreachable workspace)")
    if c.batch < 1 or c.max_tries < 1:
        raise RfmaError("sampling.batch and sampling.max_tries must be >= 1")
    if c.terms < 1:
        raise RfmaError(f"exploration.terms: must be >= 1, got {c.terms}")
    if c.waypoints[0] < 2:
        raise RfmaError(f"exploration.waypoints: need at least 2 waypoints, got {list(c.waypoints)}")
    if c.waypoints_per_unit <= 0:
        raise RfmaError(f"exploration.waypoints_per_unit: must be > 0, got {c.waypoints_per_unit}")
    if not 0.0 < c.explore_acceleration_fraction <= 1.0:
        raise RfmaError(f"exploration.acceleration_fraction: must lie in (0, 1], got {c.explore_acceleration_fraction}")
    if c.check_step <= 0:
        raise RfmaError(f"path_collision_check.step_deg: must be > 0, got {math.degrees(c.check_step)}")
    if c.knot_dt <= 0:
        raise RfmaError(f"knot_dt_s: must be > 0, got {c.knot_dt}")
    if c.joint_margin < 0:
        raise RfmaError(f"joint_margin_deg: must be >= 0, got {math.degrees(c.joint_margin)}")
    return c


def _config_from_dict(d: Any, source: str) -> RfmaConfig:
    """The :class:`RfmaConfig` of a parsed RFMA YAML: its shape checked by :class:`RfmaYaml`, then its values."""
    if not isinstance(d, dict):
        raise RfmaError(f"{source}: expected a mapping at the top level")
    y = load_typed(RfmaYaml, d, source, RfmaError)
    ex, re = y.exploration, y.reach
    if y.scaffolds < 1:
        raise RfmaError(f"{source}: scaffolds: must be >= 1, got {y.scaffolds}")
    boxes = []
    for k, b in enumerate(y.environment_boxes or []):
        try:
            boxes.append(EnvironmentBox(b.name or f"box_{k}", b.size_m, b.xyz_m,
                                        tuple(math.radians(x) for x in b.rpy_deg)))
        except ValueError as exc:
            raise RfmaError(f"{source}: environment_boxes[{k}]: {exc}") from exc
    c = RfmaConfig(
        seed=y.seed, robot=y.robot, scaffolds=y.scaffolds, joint_margin=math.radians(y.joint_margin_deg),
        home=tuple(math.radians(x) for x in y.home_deg), return_home=y.return_home,
        radius=y.workspace.radius_m, x_min=y.workspace.x_min_m, z_min=y.workspace.z_min_m, boxes=tuple(boxes),
        batch=y.sampling.batch, max_tries=y.sampling.max_tries, terms=ex.terms,
        amplitude=tuple(math.radians(x) for x in _interval(ex.amplitude_deg, f"{source}: exploration.amplitude_deg",
                                                           lo_min=0.0)),
        frequency=_interval(ex.frequency, f"{source}: exploration.frequency"),
        phase=_interval(ex.phase_rad, f"{source}: exploration.phase_rad"),
        waypoints=ex.waypoints, waypoints_per_unit=ex.waypoints_per_unit,
        explore_velocity_fraction=_interval(ex.velocity_fraction, f"{source}: exploration.velocity_fraction", 1e-6,
                                            1.0),
        explore_acceleration_fraction=ex.acceleration_fraction,
        reach_velocity_fraction=_interval(re.velocity_fraction, f"{source}: reach.velocity_fraction", 1e-6, 1.0),
        knot_dt=y.knot_dt_s, check_path=y.path_collision_check.enabled,
        check_step=math.radians(y.path_collision_check.step_deg),
    )
    try:
        return _validated(c)
    except RfmaError as exc:
        raise RfmaError(f"{source}: {exc}") from exc


def load_rfma_config(path: str | Path | None = None, **overrides: Any) -> RfmaConfig:
    """Load an RFMA YAML config (default: the shipped ``proprio/configs/rfma.yaml``), then apply ``overrides``
    (RfmaConfig field names, e.g. ``scaffolds=3, seed=1``). Raises :class:`RfmaError` naming the file and a bad
    field (an unknown key with the nearest valid one)."""
    if path is None:
        text, source = resources.files("proprio.configs").joinpath("rfma.yaml").read_text(), "rfma.yaml"
    else:
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"RFMA config not found: {path}")
        text, source = path.read_text(), str(path)
    cfg = _config_from_dict(read_yaml(text=text, source=source, error=RfmaError), source)
    return cfg.replace(**overrides) if overrides else cfg
