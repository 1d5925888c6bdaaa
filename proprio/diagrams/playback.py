"""Meshcat playback of a run: the arm moving, the estimated and the true flange force as arrows, each link tinted by
its joint's torque residual, recorded as a Meshcat animation (its time slider scrubs through the run) and exportable
as one self-contained HTML file.

The diagram is the robot's ``MultibodyPlant`` + ``SceneGraph`` (:func:`proprio.plant.AddRobot` with its simple visual
geometry, :func:`proprio.urdf.visual_shapes`) and Drake's ``MeshcatVisualizer``; each animation frame sets the plant's
positions and force-publishes the diagram while Meshcat records. The arrows and the link colours are written into the
same recording (``MeshcatAnimation``). Drake's Meshcat serves on localhost only here.

What is shown (:class:`Playback`, world frame, SI):

* the arm at ``q [N,n]`` rad;
* ``f_est [N,3]`` N — an observer's estimate of the force the environment exerts on the robot at the flange, and
  ``f_true [N,3]`` N where the run knows it (a twin's ``f_ext``); arrows from the flange origin along f, length
  ``force_scale`` m per N;
* ``residual [N,n]`` N·m — the joint torque the model and the known external force leave unexplained,
  ``e = τ_J − τ_dyn + Jᵀ f_true = −(τ̂_ext − Jᵀ f_true)`` (the diagnosis' sign, e = τ_meas − τ_sim; without a true force
  it is the plain model gap τ_J − τ_dyn, which under an unknown contact also holds −Jᵀ f_ext). Link i (moved by joint
  i) is drawn grey at e_i = 0, red towards +``residual_scale``, blue towards −``residual_scale`` (saturating).

Frames (the subsampling rule, :func:`frame_groups`): frames are ``h`` seconds of the run apart, with
``h = max(1/fps, duration/(max_frames − 1))`` and ``round(duration/h) + 1`` frames — real time at ``fps`` frames per second up to ``max_frames`` frames
(default 30 fps, 1800 frames: one minute), longer runs play faster (by ``h·fps``). Every sample belongs to exactly one
frame's group (the samples within ±h/2 of the frame time): the arm is drawn at the group's sample nearest the frame
time; the arrows and tints are the group means (a box filter against aliasing the noisy 1 kHz torques).

Gaps: the samples inside a gap of the log (:attr:`EstimationResult.gap`, a dropout the conditioning flags) are not
played — nothing was measured there. A frame whose time lies inside a gap shows nothing: the arm and the arrows are
hidden (Meshcat's ``visible`` property in the animation), so neither motion nor force is animated across the hole,
and the tint scale comes from the measured frames only; the legend lists the gaps.
"""
from __future__ import annotations

import gc
import html
import json
import logging
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.geometry import (Cylinder, Meshcat, MeshcatCone, MeshcatParams, MeshcatVisualizer,
                              MeshcatVisualizerParams, Rgba, Role)
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.framework import DiagramBuilder

from proprio.conditioning import ConditioningConfig
from proprio.description import RobotDescription
from proprio.diagrams.estimation import (EstimationResult, TorqueModel, check_recording_matches, estimate_wrench,
                                         load_torque_model)
from proprio.io import atomic_write_text
from proprio.kinematics import flange_position, point_jacobian
from proprio.plant import AddRobot
from proprio.recording import Recording, RecordingError, load_recording

__all__ = ["Playback", "PlaybackSettings", "FrameGroups", "PlaybackInfo", "frame_groups", "torque_residual",
           "playback_from_estimate", "playback_from_recording", "load_playback", "record_playback", "playback_html",
           "write_playback_html", "start_meshcat", "ArmView", "ARROW_RGBA", "ROOT"]

ROOT = "/proprio"                   # Meshcat path of the arrows
VISUALIZER_PREFIX = "visualizer"    # MeshcatVisualizer's prefix (its paths are /drake/<prefix>/...)
ARROW_RGBA = {"estimated": (0.55, 0.15, 0.85, 1.0), "true": (0.10, 0.65, 0.20, 1.0)}
NEUTRAL_RGB = np.array([0.80, 0.80, 0.80])
POSITIVE_RGB = np.array([0.85, 0.08, 0.08])
NEGATIVE_RGB = np.array([0.10, 0.30, 0.90])
SHAFT_RADIUS, HEAD_RADIUS, HEAD_LENGTH = 0.008, 0.02, 0.05    # [m]
MIN_RESIDUAL_SCALE = 0.1                                       # [N·m] floor of the automatic tint scale


@dataclass(frozen=True)
class Playback:
    """A run to play: ``t [N]`` s, ``q [N,n]`` rad, optional ``f_est``, ``f_true [N,3]`` N (world frame, on the
    robot at the flange) and ``residual [N,n]`` N·m (module docstring); ``title`` and ``f_est_label`` for the legend;
    ``gaps``: ``(start, end)`` [s, the clock of ``t``] of each gap of the log between two played samples, where nothing
    was measured (module docstring)."""
    description: RobotDescription
    t: np.ndarray
    q: np.ndarray
    f_est: np.ndarray | None = None
    f_true: np.ndarray | None = None
    residual: np.ndarray | None = None
    title: str = ""
    f_est_label: str = "estimated"
    gaps: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        n_s, n = self.t.shape[0], self.description.n
        if self.t.ndim != 1 or n_s < 1 or np.any(np.diff(self.t) <= 0):
            raise RecordingError("playback: 't' must be a non-empty, strictly increasing [N] array")
        for name, shape in (("q", (n_s, n)), ("f_est", (n_s, 3)), ("f_true", (n_s, 3)), ("residual", (n_s, n))):
            a = getattr(self, name)
            if a is not None and (a.shape != shape or not np.all(np.isfinite(a))):
                raise RecordingError(f"playback: '{name}' must be a finite array of shape {list(shape)}, got "
                                     f"{list(a.shape)}")

    def window(self, start_s: float | None = None, end_s: float | None = None) -> "Playback":
        """The samples with ``start_s ≤ t − t[0] ≤ end_s`` [s] (None: from the start / to the end)."""
        keep = _window_mask(self.t, start_s, end_s)
        cut = lambda a: None if a is None else a[keep]  # noqa: E731
        t = self.t[keep]
        gaps = tuple((a, b) for a, b in self.gaps if a >= t[0] and b <= t[-1])
        return Playback(self.description, t, self.q[keep], cut(self.f_est), cut(self.f_true),
                        cut(self.residual), self.title, self.f_est_label, gaps)

    def hidden(self, times: np.ndarray) -> np.ndarray:
        """``bool [K]``: which of ``times`` [s] lie strictly inside a gap (nothing to show there)."""
        out = np.zeros(np.shape(times), dtype=bool)
        for a, b in self.gaps:
            out |= (times > a) & (times < b)
        return out


def _window_mask(t: np.ndarray, start_s: float | None, end_s: float | None) -> np.ndarray:
    rel = t - t[0]
    keep = (rel >= (start_s or 0.0)) & (rel <= (np.inf if end_s is None else end_s))
    if keep.sum() < 2:
        span = f"{start_s or 0.0:g} s to {'the end' if end_s is None else f'{end_s:g} s'}"
        raise RecordingError(f"window from {span} keeps {int(keep.sum())} of the run's {t.size} samples (it lasts "
                             f"{rel[-1]:.6g} s; at least 2 are needed)")
    return keep


@dataclass(frozen=True)
class PlaybackSettings:
    """Animation options: ``fps`` frames per second, at most ``max_frames`` frames (module docstring), arrow length
    ``force_scale`` [m/N], tint saturation ``residual_scale`` [N·m] (None: the 95th percentile of |e| over all
    joints and frames, at least 0.1 N·m)."""
    fps: float = 30.0
    max_frames: int = 1800
    force_scale: float = 0.02
    residual_scale: float | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be > 0, got {self.fps}")
        if self.max_frames < 2:
            raise ValueError(f"max_frames must be >= 2, got {self.max_frames}")
        if not (np.isfinite(self.force_scale) and self.force_scale > 0):
            raise ValueError(f"force_scale must be > 0 m/N, got {self.force_scale}")
        if self.residual_scale is not None and not (np.isfinite(self.residual_scale) and self.residual_scale > 0):
            raise ValueError(f"residual_scale must be > 0 N·m, got {self.residual_scale}")


@dataclass(frozen=True)
class FrameGroups:
    """The frames of a run (:func:`frame_groups`): frame k shows the data at ``times[k]`` s; its samples are
    ``bounds[k]:bounds[k+1]`` and ``nearest[k]`` is the sample closest to ``times[k]``. ``period`` h [s] of data per
    frame; the animation plays ``speedup`` = h·fps times real time."""
    times: np.ndarray
    nearest: np.ndarray
    bounds: np.ndarray
    period: float
    speedup: float

    @property
    def count(self) -> int:
        return int(self.times.size)

    def mean(self, x: np.ndarray) -> np.ndarray:
        """Per-frame mean of ``x [N, ...]`` over each group (the nearest sample where a group is empty)."""
        flat = x.reshape(x.shape[0], -1)
        csum = np.vstack([np.zeros((1, flat.shape[1])), np.cumsum(flat, axis=0)])
        size = np.diff(self.bounds)
        out = (csum[self.bounds[1:]] - csum[self.bounds[:-1]]) / np.maximum(size, 1)[:, None]
        out[size == 0] = flat[self.nearest[size == 0]]
        return out.reshape((self.count,) + x.shape[1:])


def frame_groups(t: np.ndarray, fps: float = 30.0, max_frames: int = 1800) -> FrameGroups:
    """The frames of the subsampling rule of the module docstring for sample times ``t [N]`` s."""
    t = np.asarray(t, dtype=float)
    duration = float(t[-1] - t[0])
    h = max(1.0 / fps, duration / (max_frames - 1))
    count = int(np.floor(duration / h + 0.5)) + 1          # the last frame's group reaches the last sample
    times = t[0] + h * np.arange(count)
    bounds = np.searchsorted(t, t[0] + h * (np.arange(count + 1) - 0.5))
    bounds[0], bounds[-1] = 0, t.size
    right = np.clip(np.searchsorted(t, times), 1, t.size - 1) if t.size > 1 else np.zeros(count, dtype=int)
    nearest = right if t.size == 1 else np.where(np.abs(t[right - 1] - times) <= np.abs(t[right] - times),
                                                 right - 1, right)
    return FrameGroups(times, nearest, bounds, h, h * fps)


def _wrench_torque(desc: RobotDescription, q: np.ndarray, wrench: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Jᵀ w ``[N,n]`` N·m of a wrench ``[N,6]`` ([f; m], world frame) acting at ``point`` in the flange frame."""
    jac = point_jacobian(desc, q, point)                      # [N,6,n], rows [ω; v]
    return np.einsum("nkj,nk->nj", jac[:, 3:], wrench[:, :3]) + np.einsum("nkj,nk->nj", jac[:, :3], wrench[:, 3:])


def torque_residual(res: EstimationResult, desc: RobotDescription, observer: str = "jacobian") -> np.ndarray:
    """``e = −(τ̂_ext − Jᵀ f_true)`` ``[N,n]`` N·m of an estimation result (module docstring): with the Jacobian
    observer τ̂_ext = τ_dyn − τ_J, so e = τ_J − τ_dyn + Jᵀ f_true; ``f_true`` = 0 when the run has none."""
    e = -np.asarray(res.tau_ext[observer], dtype=float)
    if res.f_true is not None:
        point = np.asarray(res.meta.get("mapping", {}).get("contact_point", (0.0, 0.0, 0.0)), dtype=float)
        e = e + _wrench_torque(desc, res.q, res.f_true, point)
    return e


def playback_from_estimate(res: EstimationResult, desc: RobotDescription, observer: str = "jacobian",
                           title: str = "") -> Playback:
    """The playback of an estimation result (``proprio estimate``'s ``estimates.npz``, :meth:`EstimationResult.load`):
    the arm at the filtered q the observers used, ``observer``'s force estimate, the true force and
    :func:`torque_residual` — at the measured samples only: the samples inside gaps of the log are left out and
    become :attr:`Playback.gaps`."""
    if observer not in res.wrench:
        raise ValueError(f"observer must be one of {sorted(res.wrench)}, got {observer!r}")
    keep = ~res.gap
    if keep.sum() < 1:
        raise RecordingError("playback: every sample lies inside a gap of the log; nothing to show")
    t = res.t - res.t[0]
    edges = np.flatnonzero(np.diff(keep.astype(np.int8)))     # keep[k] != keep[k + 1]
    before, after = edges[keep[edges]], edges[~keep[edges]] + 1  # the samples around each gap
    if not keep[0]:
        after = after[1:]                                        # a gap at the start has no sample before it,
    before = before[:after.size]                                 # one at the end none after it
    gaps = tuple((float(t[a]), float(t[b])) for a, b in zip(before, after))
    cut = lambda a: None if a is None else np.asarray(a)[keep]  # noqa: E731
    return Playback(desc, t[keep], res.q[keep], f_est=res.wrench[observer][keep, :3],
                    f_true=None if res.f_true is None else res.f_true[keep, :3],
                    residual=cut(torque_residual(res, desc, observer)), title=title,
                    f_est_label=f"estimated ({observer} observer, model {res.meta.get('model', '?')})", gaps=gaps)


def playback_from_recording(rec: Recording, model: TorqueModel | RobotDescription, observer: str = "jacobian",
                            conditioning: ConditioningConfig = ConditioningConfig(), title: str = "") -> Playback:
    """The playback of a Recording (measured, or a twin run): the estimation diagram runs over it with ``model``
    (:func:`~proprio.diagrams.estimation.estimate_wrench`, what ``proprio estimate`` writes; a jittered log is
    resampled onto a uniform grid first), then :func:`playback_from_estimate`."""
    desc = model if isinstance(model, RobotDescription) else model.description
    return playback_from_estimate(estimate_wrench(model, rec, conditioning=conditioning), desc, observer, title)


def _torque_model(spec: str | Path | None, guesses: list, source: Path) -> TorqueModel:
    """``spec`` (see :func:`~proprio.diagrams.estimation.load_torque_model`), else the first of the run's own robot
    names that loads."""
    if spec is not None:
        return load_torque_model(spec)
    for guess in (g for g in guesses if g):
        try:
            return load_torque_model(guess)
        except (ValueError, FileNotFoundError):
            continue
    raise ValueError(f"{source}: its robot {[g for g in guesses if g] or '(not recorded)'} is not a shipped robot "
                     "name; give the model (--model: a robot name, YAML/URDF or directory, or an identified .npz)")


def load_playback(source: str | Path, model: str | Path | None = None, observer: str = "jacobian",
                  start_s: float | None = None, end_s: float | None = None,
                  conditioning: ConditioningConfig = ConditioningConfig()) -> Playback:
    """The playback of a file: an ``estimates.npz`` written by ``proprio estimate`` (or its output directory), or a
    Recording ``.npz`` (a twin run from ``proprio simulate``, a measured log, an LWR 4+ file), over which the
    estimation diagram runs with ``model`` (default: the robot the file names). ``start_s``/``end_s`` [s from the
    start] cut a window first."""
    path = Path(source)
    if path.is_dir():
        path = path / "estimates.npz"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as z:
            is_estimate = "wrench_jacobian" in z.files
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise RecordingError(f"{path}: not a readable .npz, truncated or corrupted ({exc})") from None
    if is_estimate:
        res = EstimationResult.load(path)
        desc = _torque_model(model, [res.meta.get("recording", {}).get("robot"), res.meta.get("model")],
                             path).description
        return playback_from_estimate(res, desc, observer, title=str(path)).window(start_s, end_s)
    rec = load_recording(path)
    keep = np.flatnonzero(_window_mask(rec.t, start_s, end_s))
    rec = rec.slice(int(keep[0]), int(keep[-1]) + 1)
    torque_model = _torque_model(model, [rec.meta.get("robot")], path)
    try:                                                    # the one check that the log is of the model's robot
        check_recording_matches(rec, torque_model.description)
    except RecordingError as exc:
        raise RecordingError(f"{path}: {str(exc).removeprefix('recording: ')}; pass --model for its robot") from None
    return playback_from_recording(rec, torque_model, observer, conditioning, title=str(path))


@dataclass(frozen=True)
class PlaybackInfo:
    """What :func:`record_playback` recorded: the frames, the animation rate [1/s], the arrow scale [m/N], the tint
    scale [N·m], the Meshcat paths of the arrows and of each link's geometries, and ``hidden [K]``: the frames inside
    a gap of the log, which show nothing."""
    frames: FrameGroups
    fps: float
    force_scale: float
    residual_scale: float | None
    arrow_paths: dict[str, str]
    link_paths: dict[str, list[str]]
    hidden: np.ndarray


def start_meshcat(port: int | None = None, quiet: bool = False) -> Meshcat:
    """A Meshcat server on localhost only (``port`` None: the first free one from 7000; 0: any free port);
    ``quiet`` keeps Drake from logging its URL."""
    logger = logging.getLogger("drake")
    level = logger.level
    if quiet:
        logger.setLevel(max(level, logging.WARNING))
    try:
        return Meshcat(MeshcatParams(host="localhost", port=port))
    finally:
        logger.setLevel(level)


def _z_to_quaternions(u: np.ndarray) -> np.ndarray:
    """Unit quaternions ``[K,4]`` (w, x, y, z) rotating +z onto the unit vectors ``u [K,3]`` (vectorised)."""
    q = np.column_stack([1.0 + u[:, 2], -u[:, 1], u[:, 0], np.zeros(len(u))])
    flip = q[:, 0] < 1e-9                                  # u ≈ −z: half turn about x
    q[flip] = (0.0, 1.0, 0.0, 0.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _tints(e: np.ndarray, scale: float) -> np.ndarray:
    """RGB ``[..., 3]`` of residuals ``e``: grey at 0, red at +scale, blue at −scale (linear, saturating)."""
    a = np.clip(e / scale, -1.0, 1.0)[..., None]
    return NEUTRAL_RGB + np.where(a > 0, a * (POSITIVE_RGB - NEUTRAL_RGB), -a * (NEGATIVE_RGB - NEUTRAL_RGB))


def _add_arrow(meshcat: Meshcat, path: str, rgba: tuple[float, ...]) -> None:
    """An arrow along +z of ``path``: a unit shaft (scaled in z per frame) and a cone head (moved per frame)."""
    color = Rgba(*rgba)
    meshcat.SetObject(f"{path}/shaft/body", Cylinder(SHAFT_RADIUS, 1.0), color)
    meshcat.SetTransform(f"{path}/shaft/body", RigidTransform([0.0, 0.0, 0.5]))
    meshcat.SetObject(f"{path}/head/cone", MeshcatCone(HEAD_LENGTH, HEAD_RADIUS, HEAD_RADIUS), color)
    # the cone's tip is at its origin, opening along +z: turn it over and lift it so the tip points along +z
    meshcat.SetTransform(f"{path}/head/cone", RigidTransform(RollPitchYaw(np.pi, 0.0, 0.0), [0.0, 0.0, HEAD_LENGTH]))


def _link_geometry_paths(plant, scene_graph, desc: RobotDescription, meshcat: Meshcat) -> dict[str, list[str]]:
    """Meshcat paths of each link's illustration geometries as MeshcatVisualizer names them."""
    inspector = scene_graph.model_inspector()
    out: dict[str, list[str]] = {}
    for link in desc.links:
        frame = plant.GetBodyFrameIdOrThrow(plant.GetBodyByName(link.name).index())
        base = f"/drake/{VISUALIZER_PREFIX}/{inspector.GetName(frame).replace('::', '/')}"
        paths = [f"{base}/{inspector.GetName(g).replace('::', '/')}"
                 for g in inspector.GetGeometries(frame, Role.kIllustration)]
        missing = [p for p in paths if not meshcat.HasPath(p)]
        if missing:
            raise RuntimeError(f"playback: Meshcat has no path {missing[0]} (MeshcatVisualizer's naming changed?)")
        out[link.name] = paths
    return out


class ArmView:
    """The arm of ``desc`` drawn in ``meshcat``: a Diagram of its plant + scene graph (with the visual geometry of
    :func:`proprio.urdf.visual_shapes`) and a ``MeshcatVisualizer``, posed on demand by :meth:`show`."""

    def __init__(self, desc: RobotDescription, meshcat: Meshcat):
        builder = DiagramBuilder()
        self.description, self.meshcat = desc, meshcat
        self.robot = AddRobot(builder, desc, visual=True)
        MeshcatVisualizer.AddToBuilder(builder, self.robot.scene_graph, meshcat,
                                       MeshcatVisualizerParams(prefix=VISUALIZER_PREFIX))
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self._plant_context = self.robot.plant.GetMyContextFromRoot(self.context)

    def show(self, q: np.ndarray, time: float = 0.0) -> None:
        """Draw the arm at ``q [n]`` rad (published at context time ``time`` [s], which a Meshcat recording uses)."""
        self.context.SetTime(time)
        self.robot.plant.SetPositions(self._plant_context, self.robot.instance, np.asarray(q, dtype=float))
        self.diagram.ForcedPublish(self.context)


def record_playback(pb: Playback, meshcat: Meshcat, settings: PlaybackSettings = PlaybackSettings()) -> PlaybackInfo:
    """Record ``pb`` into ``meshcat`` as an animation and publish it (its time slider is in the Meshcat controls,
    under Animations). The frames follow :func:`frame_groups`; the per-frame arrows and tints are computed vectorised
    and written into the recording."""
    desc = pb.description
    frames = frame_groups(pb.t, settings.fps, settings.max_frames)
    arm = ArmView(desc, meshcat)
    q_frames = pb.q[frames.nearest]
    hidden = pb.hidden(frames.times)
    meshcat.Delete(ROOT)
    meshcat.DeleteRecording()
    meshcat.StartRecording(settings.fps, set_visualizations_while_recording=False)
    arm.show(q_frames[0])                          # creates the geometry (SetObject is never deferred)
    link_paths = _link_geometry_paths(arm.robot.plant, arm.robot.scene_graph, desc, meshcat)
    arrows = {name: f for name, f in (("estimated", pb.f_est), ("true", pb.f_true)) if f is not None}
    arrow_paths = {name: f"{ROOT}/force_{name}" for name in arrows}
    for name, path in arrow_paths.items():
        _add_arrow(meshcat, path, ARROW_RGBA[name])
    anim = meshcat.get_mutable_recording()
    origin = flange_position(desc, q_frames)                                    # [K,3]
    arrow_frames = {}
    for name, f in arrows.items():
        fk = frames.mean(f)
        norm = np.linalg.norm(fk, axis=1)
        direction = np.where(norm[:, None] > 1e-9, fk / np.maximum(norm, 1e-300)[:, None], (0.0, 0.0, 1.0))
        length = norm * settings.force_scale                                    # whole arrow [m]
        head = np.minimum(length / HEAD_LENGTH, 1.0)                            # head scale (short arrows)
        shaft = np.maximum(length - HEAD_LENGTH * head, 1e-6)
        arrow_frames[name] = (_z_to_quaternions(direction), shaft, head)
    residual_scale = None
    tints = None
    if pb.residual is not None:
        ek = frames.mean(pb.residual)                                           # [K,n]
        shown = ek[~hidden] if (~hidden).any() else ek
        residual_scale = settings.residual_scale or max(float(np.percentile(np.abs(shown), 95)), MIN_RESIDUAL_SCALE)
        tints = _tints(ek, residual_scale)                                      # [K,n,3]
    arm_path = f"/drake/{VISUALIZER_PREFIX}"
    for k in range(frames.count):
        if pb.gaps:                                        # hide everything inside a gap, show it again after
            for path in [arm_path, *arrow_paths.values()]:
                anim.SetProperty(k, path, "visible", not hidden[k])
        if hidden[k]:
            continue
        arm.show(q_frames[k], (k + 0.25) / settings.fps)   # recorded at frame ⌊time · fps⌋ (or its rounding) = k
        for name, path in arrow_paths.items():
            quat, shaft, head = arrow_frames[name]
            anim.SetTransform(k, path, RigidTransform(Quaternion(quat[k]), origin[k]))
            anim.SetProperty(k, f"{path}/shaft", "scale", [1.0, 1.0, float(shaft[k])])
            anim.SetTransform(k, f"{path}/head", RigidTransform([0.0, 0.0, float(shaft[k])]))
            anim.SetProperty(k, f"{path}/head", "scale", [float(head[k])] * 3)
        if tints is not None:
            for j, link in enumerate(desc.links):
                for path in link_paths[link.name]:
                    anim.SetProperty(k, f"{path}/<object>", "material.color", tints[k, j].tolist())
    meshcat.StopRecording()
    meshcat.PublishRecording()
    return PlaybackInfo(frames, settings.fps, settings.force_scale, residual_scale, arrow_paths, link_paths, hidden)


def _swatch(rgb) -> str:
    r, g, b = (int(round(255 * c)) for c in rgb[:3])
    return f"<span style='display:inline-block;width:12px;height:12px;background:rgb({r},{g},{b})'></span>"


def _legend(pb: Playback, info: PlaybackInfo) -> str:
    """A fixed overlay with what the colours and arrows mean, and a JSON summary of the animation for tools."""
    fr = info.frames
    lines = [f"<b>{html.escape(pb.title or pb.description.name)}</b>",
             f"{fr.count} frames at {info.fps:g} fps, {fr.period * 1e3:.1f} ms of data each "
             f"(×{fr.speedup:.2f} real time); time slider: Open Controls → Animations"]
    if info.arrow_paths:
        lines.append("force on the robot at the flange, " + f"{100 * info.force_scale:g} cm per N: " + ", ".join(
            f"{_swatch(ARROW_RGBA[n])} {html.escape(pb.f_est_label if n == 'estimated' else 'true')}"
            for n in info.arrow_paths))
    if info.residual_scale is not None:
        s = info.residual_scale
        lines.append(f"link i tinted by joint i's torque residual e = τ_J − τ_model + Jᵀf_true: "
                     f"{_swatch(NEGATIVE_RGB)} −{s:.3g} N·m {_swatch(NEUTRAL_RGB)} 0 {_swatch(POSITIVE_RGB)} "
                     f"+{s:.3g} N·m")
    if pb.gaps:
        lines.append(f"{len(pb.gaps)} gap(s) in the log, nothing shown (no data): " + ", ".join(
            f"{a:.3f}–{b:.3f} s" for a, b in pb.gaps))
    summary = {"title": pb.title, "robot": pb.description.name, "frames": fr.count, "fps": info.fps,
               "frame_period_s": fr.period, "speedup": fr.speedup, "duration_s": float(pb.t[-1] - pb.t[0]),
               "samples": int(pb.t.size), "force_scale_m_per_N": info.force_scale,
               "residual_scale_Nm": info.residual_scale, "arrows": info.arrow_paths,
               "links": info.link_paths, "gaps_s": [list(g) for g in pb.gaps],
               "hidden_frames": int(info.hidden.sum())}
    return ("<div id='proprio-legend' style='position:fixed;left:8px;bottom:8px;max-width:46em;padding:6px 9px;"
            "background:rgba(255,255,255,0.85);font:12px sans-serif;border-radius:4px'>" + "<br>".join(lines)
            + "</div>\n<script type='application/json' id='proprio-playback'>"
            + json.dumps(summary).replace("</", "<\\/") + "</script>\n")


def playback_html(pb: Playback, settings: PlaybackSettings = PlaybackSettings(), port: int | None = 0
                  ) -> tuple[str, PlaybackInfo]:
    """The self-contained HTML of ``pb``'s animation (Meshcat's ``StaticHtml``: the viewer, the scene, the recorded
    animation and a legend; no network needed to view it) and what was recorded. A temporary Meshcat serves on
    localhost while it is made, and is freed on the calling thread before this returns: Drake's ``~Meshcat`` asserts
    the thread that made it, and the recording Diagram holds it in reference cycles, which a garbage collection on
    another thread (a Jupyter kernel's) would otherwise free there and abort the process."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        meshcat = start_meshcat(port, quiet=True)
        info = record_playback(pb, meshcat, settings)
        page = meshcat.StaticHtml()
        del meshcat
    finally:
        gc.collect()
        if collecting:
            gc.enable()
    cut = page.rfind("</body>")
    if cut < 0:
        raise RuntimeError("playback: Meshcat's StaticHtml has no </body>")
    return page[:cut] + _legend(pb, info) + page[cut:], info


def write_playback_html(pb: Playback, path: str | Path, settings: PlaybackSettings = PlaybackSettings()
                        ) -> tuple[Path, PlaybackInfo]:
    """Write :func:`playback_html` to ``path`` atomically; returns the path and what was recorded."""
    page, info = playback_html(pb, settings)
    path = Path(path)
    atomic_write_text(path, page)
    return path, info
