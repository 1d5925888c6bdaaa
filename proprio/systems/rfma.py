"""RFMA — the thesis' Random Fine Motion Generation Algorithm (§4.3, Algorithm 4.10, eq. 4.35–4.37).

The path alternates *reach* and *explore* phases around L random scaffold configurations:

1. **Scaffolds.** Candidates are drawn uniformly in ``[lower + margin, upper − margin]`` (Table 2.3 limits, 2°
   margin) in vectorised batches, forward-kinematised in one call (:func:`proprio.kinematics.flange_position`) and
   kept if the flange position p_EE, measured from the **robot base origin** (base-link frame), lies in the
   quarter sphere ``x > x_min, z > z_min, ‖p_EE‖ < radius`` (0, 0, 0.8 m); only the survivors are checked for
   self-collision and collision with the configured environment boxes by Drake's SceneGraph
   (:class:`proprio.collision.CollisionChecker`). Sampling stops with :class:`RfmaError` ("found K of N
   after M tries") when ``sampling.max_tries`` candidates do not give L scaffolds.
2. **Ordering.** Greedy nearest neighbour in joint space on a scipy kd-tree, starting from the scaffold nearest the
   home configuration (Algorithm 4.10 starts from the first sample; starting near home shortens the first reach).
   With ``path_collision_check`` on (default), the straight joint-space reach to the nearest remaining scaffold is
   checked every ``step_deg`` of joint motion; if it collides, the next-nearest scaffold is taken, and if no
   remaining scaffold can be reached directly the arm first retracts home (an extra reach phase). The thesis
   ensures collision-free reach paths in simulation (Fig. 4.8).
3. **Exploration** after each scaffold (eq. 4.35): per joint j, ``e_j(t) = Σ_{k=1}^{3} A_k sin(2π f_k t + φ_k)``
   with ``A_k ∈ [0.5, 3]°``, ``f_k ∈ [−4, 4]``, ``φ_k ∈ [0, 2π]`` and ``T ∈ [2000, 2500]`` waypoints (eq. 4.36).
   **Unit of f:** the thesis leaves it open; here ``t = waypoint index / waypoints_per_unit`` (600 by default), so
   f counts cycles per 600 waypoints: a phase of 2250 waypoints holds up to 15 cycles of each term, i.e. many
   direction reversals per joint. The speed is then set by the time parameterisation at 10–30 % of the velocity
   limits, not by the waypoint count, so the exploration stays inside its speed band whatever f is; the unit only
   trades phase duration against cycles per phase, and 600 gives the thesis' ≈1 h for 150 scaffolds (≈22 s per
   exploration, like its 100 waypoints/s). The waypoints are ``q_scaf + e(t) − e(0)``, t = 0…T, so that the
   exploration starts at the scaffold (eq. 4.35 is not 0 at t = 0).
   A joint whose exploration would leave ``[lower + margin, upper − margin]`` has its three terms redrawn (up to
   ``_REDRAWS`` times); if none fits (scaffold right at the margin), its amplitudes are scaled down just enough to
   fit, and the phase/joint is recorded in :attr:`RfmaPath.scaled`. With ``path_collision_check`` on, an
   exploration whose waypoints collide is redrawn (and, around a crowded scaffold, shrunk towards it).
4. **Path** (eq. 4.37): ``C = {home, q_1^scaf, e_1, …, q_L^scaf, e_L[, home]}``.
5. **Timing** (:mod:`proprio.systems.trajectories`): each reach is a joint-wise linear rest-to-rest motion at a
   relative speed and acceleration ρ ~ U[0.6, 0.9] of the limits; each exploration runs at ρ ~ U[0.1, 0.3] of the
   velocity limits (and below ``acceleration_fraction`` of the acceleration limits).

Everything random is drawn from ``np.random.default_rng(config.seed)``: the same config gives the same trajectory.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from scipy.spatial import cKDTree
from proprio.progress import progress_bar

from proprio.description import RobotDescription, load_robot
from proprio.kinematics import chain_geometry, flange_jacobian, flange_position
from proprio.collision import CollisionChecker
from proprio.plots.trajectory import plot_flange_path
from proprio.systems.rfma_config import RfmaConfig, RfmaError, load_rfma_config
from proprio.systems.trajectories import Phase, TimedPath, sample_trajectory, save_trajectory, time_parameterize

__all__ = ["RfmaError", "RfmaConfig", "RfmaPath", "load_rfma_config", "flange_in_workspace", "sample_scaffolds",
           "unvisited_by_distance", "segment_in_collision", "waypoints_in_collision", "exploration_waypoints",
           "generate_rfma_path", "rfma_trajectory", "generate_rfma", "trajectory_meta", "plot_trajectory",
           "demo_trajectory"]

_REDRAWS = 50


# ---------------------------------------------------------------------------------------------------------------
# scaffolds
# ---------------------------------------------------------------------------------------------------------------
def flange_in_workspace(desc: RobotDescription, q: np.ndarray, cfg: RfmaConfig) -> np.ndarray:
    """``bool [N]``: the flange of ``q [N,n]`` lies in the quarter sphere of ``cfg`` (base-origin frame)."""
    geo = chain_geometry(desc)
    p_world = flange_position(geo, q)
    p = (p_world - geo.world_base[:3, 3]) @ geo.world_base[:3, :3]      # into the base-link frame
    return (p[:, 0] > cfg.x_min) & (p[:, 2] > cfg.z_min) & (np.linalg.norm(p, axis=1) < cfg.radius)


def sample_scaffolds(desc: RobotDescription, cfg: RfmaConfig, rng: np.random.Generator,
                     checker: CollisionChecker | None = None, progress: bool = False) -> tuple[np.ndarray, int]:
    """Draw ``cfg.scaffolds`` feasible configurations ``[L, n]`` [rad] (step 1 of the module docstring).

    Returns ``(scaffolds, tries)`` with ``tries`` the number of candidates drawn. Raises :class:`RfmaError` when
    ``cfg.max_tries`` candidates are exhausted.
    """
    checker = checker or CollisionChecker(desc, cfg.boxes)
    lo, hi = desc.lower + cfg.joint_margin, desc.upper - cfg.joint_margin
    if np.any(lo >= hi):
        raise RfmaError(f"joint_margin_deg={math.degrees(cfg.joint_margin)} leaves no range for joint "
                        f"{desc.joint_names[int(np.argmax(lo >= hi))]}")
    found: list[np.ndarray] = []
    tries = in_ws = 0
    with progress_bar(total=cfg.scaffolds, desc="scaffolds", unit="cfg", enabled=progress, leave=False) as bar:
        while len(found) < cfg.scaffolds and tries < cfg.max_tries:
            m = min(cfg.batch, cfg.max_tries - tries)
            cand = rng.uniform(lo, hi, size=(m, desc.n))
            tries += m
            cand = cand[flange_in_workspace(desc, cand, cfg)]
            in_ws += cand.shape[0]
            for q in cand:                                    # SceneGraph queries only for the survivors
                if not checker.in_collision(q)[0]:
                    found.append(q)
                    bar.update(1)
                    if len(found) == cfg.scaffolds:
                        break
    if len(found) < cfg.scaffolds:
        if in_ws == 0:
            raise RfmaError(f"unreachable workspace: none of {tries} random configurations puts the flange in "
                            f"x > {cfg.x_min} m, z > {cfg.z_min} m, |p| < {cfg.radius} m; "
                            f"found 0 of {cfg.scaffolds} scaffolds after {tries} tries")
        raise RfmaError(f"found {len(found)} of {cfg.scaffolds} scaffolds after {tries} tries "
                        f"({in_ws} in the workspace, the rest in collision); relax the workspace or environment "
                        "boxes, or raise sampling.max_tries")
    return np.array(found), tries


def unvisited_by_distance(tree: cKDTree, visited: np.ndarray, query: np.ndarray) -> Iterator[int]:
    """Indices of the not yet ``visited`` points of ``tree`` nearest-first from ``query`` (kd-tree queries with a
    growing k) — Algorithm 4.10's ``kd_nearest_neighbor`` over the remaining scaffolds."""
    n, k, done = visited.size, 1, 0
    while done < n:
        k = min(k, n)
        _, idx = tree.query(query, k=k)
        for i in np.atleast_1d(idx)[done:]:
            if not visited[i]:
                yield int(i)
        done, k = k, 4 * k


def segment_in_collision(checker: CollisionChecker, q0: np.ndarray, q1: np.ndarray, step: float) -> bool:
    """The joint-space segment q0 → q1 touches an obstacle or itself, checked every ``step`` [rad] of the
    fastest-moving joint."""
    n = int(np.ceil(np.max(np.abs(q1 - q0)) / step)) + 1
    s = np.linspace(0.0, 1.0, max(n, 2))[:, None]
    return checker.any_collision(q0 + s * (q1 - q0))


def waypoints_in_collision(checker: CollisionChecker, w: np.ndarray, step: float) -> bool:
    """A dense waypoint list ``[m, n]`` touches an obstacle or itself, checked on a subsequence whose joint steps
    are at most ``step`` [rad]."""
    per = float(np.max(np.abs(np.diff(w, axis=0)))) if w.shape[0] > 1 else 0.0
    stride = max(1, int(step / per)) if per > 0.0 else w.shape[0]
    idx = np.unique(np.r_[np.arange(0, w.shape[0], stride), w.shape[0] - 1])
    return checker.any_collision(w[idx])


# ---------------------------------------------------------------------------------------------------------------
# exploration (eq. 4.35-4.36)
# ---------------------------------------------------------------------------------------------------------------
def exploration_waypoints(q_scaf: np.ndarray, amplitude: np.ndarray, frequency: np.ndarray, phase: np.ndarray,
                          n_waypoints: int, waypoints_per_unit: float) -> np.ndarray:
    """Eq. 4.35 around a scaffold: ``q_scaf + e(t) − e(0)`` for waypoints 0…T, ``t = index / waypoints_per_unit``.

    ``amplitude`` [rad], ``frequency`` [cycles per unit of t], ``phase`` [rad] have shape ``[n, terms]``;
    returns ``[T+1, n]`` [rad] whose first row is ``q_scaf``.
    """
    t = np.arange(n_waypoints + 1, dtype=float)[:, None, None] / waypoints_per_unit      # [T+1,1,1]
    e = np.sum(amplitude * np.sin(2.0 * np.pi * frequency * t + phase), axis=-1)          # [T+1,n]
    return q_scaf + e - e[0]


@dataclass(frozen=True)
class RfmaPath:
    """The geometric RFMA path (eq. 4.37) and every random draw behind it (radians).

    ``waypoints [P, n]``; ``scaffolds [L, n]`` in visiting order; exploration parameters ``amplitude``,
    ``frequency``, ``phase`` ``[L, n, terms]``; ``n_waypoints [L]`` (T per phase); ``reach_fraction`` (one per
    reach phase, in order) and ``explore_fraction [L]`` relative speeds; ``phases`` for
    :func:`~proprio.systems.trajectories.time_parameterize`;
    ``scaled``: ``(phase l, joint j, factor)`` where amplitudes had to be scaled to respect the joint limits
    (factor NaN: the whole phase was shrunk towards a crowded scaffold to avoid a collision);
    ``tries``: candidates drawn for the scaffolds; ``reach_rejections``: nearest scaffolds passed over because the
    straight reach to them collided."""
    waypoints: np.ndarray
    scaffolds: np.ndarray
    amplitude: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray
    n_waypoints: np.ndarray
    reach_fraction: np.ndarray
    explore_fraction: np.ndarray
    phases: tuple[Phase, ...]
    tries: int
    scaled: tuple[tuple[int, int, float], ...] = field(default=())
    reach_rejections: int = 0

    @property
    def n_scaffolds(self) -> int:
        return int(self.scaffolds.shape[0])


def _draw_terms(rng: np.random.Generator, cfg: RfmaConfig, n: int) -> tuple[np.ndarray, ...]:
    """A_k [rad], f_k, φ_k for ``n`` joints: ``[n, terms]`` each, uniform in the configured ranges."""
    shape = (n, cfg.terms)
    return (rng.uniform(*cfg.amplitude, size=shape), rng.uniform(*cfg.frequency, size=shape),
            rng.uniform(*cfg.phase, size=shape))


def _exploration(rng: np.random.Generator, cfg: RfmaConfig, q_s: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 n_wp: int, checker: CollisionChecker | None, step: float):
    """One exploration phase around scaffold ``q_s`` inside ``[lo, hi]`` (and collision-free if ``checker``).

    Returns ``(waypoints, amplitude, frequency, phase, scaled)`` with ``scaled`` a list of ``(joint, factor)``."""
    n = q_s.size
    for _ in range(_REDRAWS):                                # redraw the phase while it collides
        amp, freq, pha = _draw_terms(rng, cfg, n)
        e = exploration_waypoints(q_s, amp, freq, pha, n_wp, cfg.waypoints_per_unit)
        for _ in range(_REDRAWS):                            # redraw the terms of joints leaving the limits
            bad = np.any((e < lo) | (e > hi), axis=0)
            if not bad.any():
                break
            amp[bad], freq[bad], pha[bad] = _draw_terms(rng, cfg, int(bad.sum()))
            e = exploration_waypoints(q_s, amp, freq, pha, n_wp, cfg.waypoints_per_unit)
        scaled = []
        for j in np.flatnonzero(np.any((e < lo) | (e > hi), axis=0)):   # scaffold at the margin: shrink to fit
            dev = e[:, j] - q_s[j]
            room = np.where(dev > 0, (hi[j] - q_s[j]) / np.maximum(dev, 1e-300),
                            (q_s[j] - lo[j]) / np.maximum(-dev, 1e-300))
            factor = float(min(1.0, room.min()))
            amp[j] *= factor
            e[:, j] = q_s[j] + factor * dev
            scaled.append((int(j), factor))
        if checker is None or not waypoints_in_collision(checker, e, step):
            return e, amp, freq, pha, scaled
    for _ in range(30):                                      # crowded scaffold: shrink towards it (it is free)
        amp *= 0.5
        e = q_s + 0.5 * (e - q_s)
        if not waypoints_in_collision(checker, e, step):
            return e, amp, freq, pha, [(j, float("nan")) for j in range(n)]
    raise RfmaError(f"no collision-free exploration found around scaffold {np.round(np.degrees(q_s), 1).tolist()} "
                    "deg")


def generate_rfma_path(desc: RobotDescription, cfg: RfmaConfig, progress: bool = False) -> RfmaPath:
    """Run RFMA (Algorithm 4.10) for ``desc``: scaffolds, ordering, explorations, reach/explore phases."""
    if len(cfg.home) != desc.n:
        raise RfmaError(f"home_deg: expected {desc.n} values for robot '{desc.name}', got {len(cfg.home)}")
    rng = np.random.default_rng(cfg.seed)
    checker = CollisionChecker(desc, cfg.boxes)
    path_checker = checker if cfg.check_path else None
    scaffolds, tries = sample_scaffolds(desc, cfg, rng, checker=checker, progress=progress)
    home = np.asarray(cfg.home, dtype=float)
    L = scaffolds.shape[0]
    lo, hi = desc.lower + cfg.joint_margin, desc.upper - cfg.joint_margin
    tree, visited = cKDTree(scaffolds), np.zeros(L, dtype=bool)
    order, draws, phases, chunks, scaled, reach_frac = [], [], [], [home[None, :]], [], []
    n_wp = rng.integers(cfg.waypoints[0], cfg.waypoints[1] + 1, size=L)
    explore_frac = rng.uniform(*cfg.explore_velocity_fraction, size=L)
    state = {"current": home, "rejected": 0}

    def reach(target: np.ndarray) -> None:                   # one joint-wise linear reach phase
        rho = float(rng.uniform(*cfg.reach_velocity_fraction))
        reach_frac.append(rho)
        phases.append(Phase(np.stack([state["current"], target]), rho, rho, "reach"))
        state["current"] = target

    def nearest_free(query: np.ndarray) -> int | None:       # nearest scaffold with a collision-free reach
        for i in unvisited_by_distance(tree, visited, query):
            if path_checker is None or not segment_in_collision(checker, state["current"], scaffolds[i],
                                                                cfg.check_step):
                return i
            state["rejected"] += 1
        return None

    query = home
    for l in progress_bar(range(L), desc="explorations", enabled=progress, leave=False):
        pick = nearest_free(query)
        if pick is None and not segment_in_collision(checker, state["current"], home, cfg.check_step):
            reach(home)                                      # boxed in: retract home, then go on from there
            chunks.append(home[None, :])
            pick = nearest_free(home)
        if pick is None:
            raise RfmaError(f"no collision-free joint-space reach from the end of exploration {l} (nor via home) "
                            f"to any of the {L - l} remaining scaffolds; try another seed or fewer boxes")
        visited[pick] = True
        order.append(pick)
        q_s = scaffolds[pick]
        reach(q_s)                                           # (q_s is the exploration's first waypoint)
        e, amp, freq, pha, sc = _exploration(rng, cfg, q_s, lo, hi, int(n_wp[l]), path_checker, cfg.check_step)
        draws.append((amp, freq, pha))
        scaled += [(l, j, f) for j, f in sc]
        phases.append(Phase(e, explore_frac[l], cfg.explore_acceleration_fraction, "explore"))
        chunks.append(e)
        query, state["current"] = q_s, e[-1]
    if cfg.return_home:
        if path_checker is not None and segment_in_collision(checker, state["current"], home, cfg.check_step):
            raise RfmaError("the joint-space reach from the last exploration back home collides; try another seed "
                            "or set return_home: false")
        reach(home)
        chunks.append(home[None, :])
    amp, freq, pha = (np.stack([d[k] for d in draws]) for k in range(3))
    return RfmaPath(waypoints=np.concatenate(chunks), scaffolds=scaffolds[order], amplitude=amp, frequency=freq,
                    phase=pha, n_waypoints=n_wp, reach_fraction=np.asarray(reach_frac), explore_fraction=explore_frac,
                    phases=tuple(phases), tries=tries, scaled=tuple(scaled), reach_rejections=state["rejected"])


def rfma_trajectory(path: RfmaPath, desc: RobotDescription, cfg: RfmaConfig) -> TimedPath:
    """Time-parameterise an RFMA path (step 5 of the module docstring)."""
    return time_parameterize(path.phases, desc, knot_dt=cfg.knot_dt)


def generate_rfma(cfg: RfmaConfig | None = None, desc: RobotDescription | None = None,
                  progress: bool = False) -> tuple[RfmaPath, TimedPath]:
    """RFMA path + its trajectory for ``cfg`` (default: the shipped config) on ``desc`` (default: ``cfg.robot``)."""
    cfg = cfg or load_rfma_config()
    desc = desc or load_robot(cfg.robot)
    path = generate_rfma_path(desc, cfg, progress=progress)
    return path, rfma_trajectory(path, desc, cfg)


def trajectory_meta(path: RfmaPath, timed: TimedPath, cfg: RfmaConfig, desc: RobotDescription) -> dict[str, Any]:
    """JSON-able metadata of an RFMA trajectory (phases, draws, config) for :func:`save_trajectory`."""
    return {"source": "rfma", "robot": desc.name, "seed": cfg.seed, "joint_names": desc.joint_names,
            **timed.meta(), "scaffolds": path.scaffolds.tolist(), "n_waypoints": path.n_waypoints.tolist(),
            "amplitude": path.amplitude.tolist(), "frequency": path.frequency.tolist(), "phase": path.phase.tolist(),
            "reach_fraction": path.reach_fraction.tolist(), "explore_fraction": path.explore_fraction.tolist(),
            "total_waypoints": int(path.waypoints.shape[0]), "tries": path.tries,
            "reach_rejections": path.reach_rejections,
            "scaled": [[l, j, f if math.isfinite(f) else None] for l, j, f in path.scaled],
            "config": cfg.to_dict()}


def plot_trajectory(traj, desc: RobotDescription, path: str | Path, rate_hz: float = 50.0, title: str = "") -> Path:
    """Write the thesis' Fig. 4.9 views of a joint trajectory as a PNG (atomically): the flange path in 3-D (world
    frame) coloured by its linear speed [m/s] (top) and the joint angles [deg] over time (bottom), sampled at
    ``rate_hz`` [Hz]."""
    t, q, qd, _ = sample_trajectory(traj, rate_hz)
    geo = chain_geometry(desc)
    p = flange_position(geo, q)
    speed = np.linalg.norm(np.einsum("nij,nj->ni", flange_jacobian(geo, q)[:, 3:, :], qd), axis=1)
    return plot_flange_path(path, t, q, p, speed, desc.joint_names, title)


def demo_trajectory(out_dir: Path, scaffolds: int = 3, seed: int = 0):
    """A short RFMA trajectory for ``proprio demo``: ``(PiecewisePolynomial, path_to_npz)``.

    Uses the shipped config with ``scaffolds`` scaffolds and exploration phases of 800–1000 waypoints (instead of
    2000–2500) so that the motion lasts roughly 20–40 s; saved as ``out_dir/rfma_demo.npz``.
    """
    cfg = load_rfma_config(scaffolds=scaffolds, seed=seed, waypoints=(800, 1000))
    desc = load_robot(cfg.robot)
    path, timed = generate_rfma(cfg, desc)
    out = save_trajectory(Path(out_dir) / "rfma_demo.npz", timed.trajectory, trajectory_meta(path, timed, cfg, desc))
    return timed.trajectory, out
