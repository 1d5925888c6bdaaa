"""RFMA (thesis §4.3, Algorithm 4.10): scaffolds, exploration statistics, limits, reproducibility, bad configs."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from scipy import stats

from proprio.description import load_robot
from proprio.collision import CollisionChecker, EnvironmentBox
from proprio.systems.rfma import (RfmaError, exploration_waypoints, flange_in_workspace, generate_rfma,
                                  load_rfma_config, sample_scaffolds, unvisited_by_distance)
from proprio.systems.trajectories import check_limits, sample_trajectory

RATE = 500.0


@pytest.fixture(scope="module")
def desc():
    return load_robot("iiwa14_identified")


@pytest.fixture(scope="module")
def cfg():
    return load_rfma_config(scaffolds=3, seed=7)


@pytest.fixture(scope="module")
def generated(desc, cfg):
    path, timed = generate_rfma(cfg, desc)
    t, q, qd, qdd = sample_trajectory(timed.trajectory, RATE)
    return path, timed, (t, q, qd, qdd)


def _phase_mask(t, timed, k):
    return (t > timed.phase_times[k]) & (t < timed.phase_times[k + 1])


def _explore_phases(timed):
    return [k for k, kind in enumerate(timed.phase_kinds) if kind == "explore"]


def test_shipped_config_matches_thesis(cfg):
    assert cfg.scaffolds == 3   # override applied
    full = load_rfma_config()
    assert full.scaffolds == 150 and full.terms == 3
    assert np.allclose(np.degrees(full.amplitude), (0.5, 3.0)) and full.frequency == (-4.0, 4.0)
    assert full.waypoints == (2000, 2500) and math.isclose(math.degrees(full.joint_margin), 2.0)
    assert full.explore_velocity_fraction == (0.1, 0.3) and full.reach_velocity_fraction == (0.6, 0.9)
    assert full.radius == 0.8 and full.x_min == 0.0 and full.z_min == 0.0


def test_every_sample_inside_limits(desc, generated):
    _, timed, _ = generated
    lim = check_limits(timed.trajectory, desc, rate_hz=1000.0)
    assert lim["velocity"] <= 0.9 * 1.01
    assert lim["acceleration"] <= 0.9 * 1.02
    assert lim["position_excess_rad"] < 0.0


def test_scaffolds_feasible(desc, cfg, generated):
    path, timed, _ = generated
    assert path.scaffolds.shape == (3, 7)
    assert flange_in_workspace(desc, path.scaffolds, cfg).all()
    assert not CollisionChecker(desc, cfg.boxes).in_collision(path.scaffolds).any()
    margin = np.radians(2.0)
    assert np.all(path.scaffolds >= desc.lower + margin) and np.all(path.scaffolds <= desc.upper - margin)
    # the trajectory passes through each scaffold at the start of its exploration phase
    for l, k in enumerate(_explore_phases(timed)):
        np.testing.assert_allclose(timed.trajectory.value(timed.phase_times[k]).ravel(), path.scaffolds[l],
                                   atol=1e-9)


def test_path_structure_eq_4_37(generated):
    path, timed, _ = generated
    assert timed.phase_kinds == ("reach", "explore") * 3 + ("reach",)
    assert path.waypoints.shape[0] == 1 + int(np.sum(path.n_waypoints + 1)) + 1
    assert np.all((path.n_waypoints >= 2000) & (path.n_waypoints <= 2500))
    np.testing.assert_allclose(path.waypoints[0], 0.0)
    np.testing.assert_allclose(path.waypoints[-1], 0.0)


def test_same_seed_same_trajectory(desc):
    c = load_rfma_config(scaffolds=2, seed=11, waypoints=(300, 400))
    _, a = generate_rfma(c, desc)
    _, b = generate_rfma(c, desc)
    ta, tb = np.asarray(a.trajectory.get_segment_times()), np.asarray(b.trajectory.get_segment_times())
    assert np.array_equal(ta, tb)
    assert np.array_equal(a.trajectory.vector_values(ta), b.trajectory.vector_values(tb))
    _, other = generate_rfma(c.replace(seed=12), desc)
    assert other.trajectory.get_number_of_segments() != a.trajectory.get_number_of_segments() or not np.allclose(
        other.trajectory.vector_values(ta[:10]), a.trajectory.vector_values(ta[:10]))


def test_reach_phases_joint_wise_linear_and_in_speed_band(desc, generated):
    path, timed, (t, q, qd, _) = generated
    reaches = [k for k, kind in enumerate(timed.phase_kinds) if kind == "reach"]
    assert len(reaches) == path.reach_fraction.size
    for r, k in enumerate(reaches):
        m = _phase_mask(t, timed, k)
        q0 = timed.trajectory.value(timed.phase_times[k]).ravel()
        q1 = timed.trajectory.value(timed.phase_times[k + 1]).ravel()
        u = (q1 - q0) / np.linalg.norm(q1 - q0)
        d = q[m] - q0
        assert np.abs(d - np.outer(d @ u, u)).max() < 5e-5          # on the joint-space line (spline error)
        peak = np.max(np.abs(qd[m]) / desc.velocity_limits)
        assert peak <= path.reach_fraction[r] * 1.01
        assert peak >= path.reach_fraction[r] * 0.97 or np.linalg.norm(q1 - q0) < 0.3   # short reaches never cruise


def _reversals(x: np.ndarray, tol: float) -> np.ndarray:
    """Indices of direction reversals of ``x`` (turning points), ignoring wiggles smaller than ``tol``."""
    turns, direction, anchor = [], 0, 0
    for i in range(1, x.size):          # small helper over one joint's samples (test only)
        if direction >= 0 and x[i] < x[anchor] - tol:
            if direction > 0:
                turns.append(anchor)
            direction, anchor = -1, i
        elif direction <= 0 and x[i] > x[anchor] + tol:
            if direction < 0:
                turns.append(anchor)
            direction, anchor = 1, i
        elif (direction > 0 and x[i] > x[anchor]) or (direction < 0 and x[i] < x[anchor]):
            anchor = i
    return np.asarray(turns, dtype=int)


def test_exploration_many_small_reversals(desc, cfg, generated):
    """Per joint: the reversal count matches the configured sinusoid (eq. 4.35) and is bounded by the frequency
    range; the excursions are bounded by the amplitude range; the speed stays in the exploration band."""
    path, timed, (t, q, qd, _) = generated
    a_lo, a_hi = cfg.amplitude
    f_max = max(abs(cfg.frequency[0]), abs(cfg.frequency[1]))
    counts = []
    for l, k in enumerate(_explore_phases(timed)):
        m = _phase_mask(t, timed, k)
        units = path.n_waypoints[l] / cfg.waypoints_per_unit           # length of the phase in units of t
        # reference: the configured sinusoid sampled finely in waypoint space
        ref = exploration_waypoints(path.scaffolds[l], path.amplitude[l], path.frequency[l], path.phase[l],
                                    int(path.n_waypoints[l]), cfg.waypoints_per_unit)
        for j in range(desc.n):
            tol = np.radians(0.05)
            n_traj = _reversals(q[m, j], tol).size
            n_ref = _reversals(ref[:, j], tol).size
            assert abs(n_traj - n_ref) <= 1, (l, j, n_traj, n_ref)
            assert n_traj <= 2 * f_max * units * cfg.terms + 1          # a 3-term sum can turn at most this often
            counts.append(n_traj)
            excursion = q[m, j] - path.scaffolds[l, j]
            if not any(s[0] == l and s[1] == j for s in path.scaled):
                assert np.all((path.amplitude[l, j] >= a_lo - 1e-12) & (path.amplitude[l, j] <= a_hi + 1e-12))
            assert np.abs(excursion).max() <= 2 * path.amplitude[l, j].sum() + 1e-6
            turns = q[m, j][_reversals(q[m, j], tol)]
            if turns.size > 1:   # swing between consecutive turning points: small (below 2·Σ A_k)
                assert np.abs(np.diff(turns)).max() <= 2 * path.amplitude[l, j].sum() + 1e-6
        peak = np.max(np.abs(qd[m]) / desc.velocity_limits)
        assert peak <= path.explore_fraction[l] * 1.01 <= cfg.explore_velocity_fraction[1] * 1.01
    counts = np.asarray(counts)
    assert np.median(counts) >= 10            # many reversals per joint and phase
    assert np.mean(counts > 0) > 0.9
    # amplitude and frequency draws follow the configured uniform ranges
    assert stats.kstest((path.amplitude.ravel() - a_lo) / (a_hi - a_lo), "uniform").pvalue > 1e-3
    assert stats.kstest((path.frequency.ravel() + 4.0) / 8.0, "uniform").pvalue > 1e-3


def test_collision_model_sanity(desc):
    cc = CollisionChecker(desc)
    assert not cc.in_collision(np.zeros(7))[0]            # links i and i+2 clear at q = 0
    assert cc.colliding_pairs(np.zeros(7)) == []
    for j in range(7):                                    # one joint swept over its whole range: no self-collision
        q = np.zeros((25, 7))
        q[:, j] = np.linspace(desc.lower[j], desc.upper[j], 25)
        assert not cc.in_collision(q).any(), desc.joint_names[j]
    folded = np.radians([-19.0, 117.0, 5.0, -118.0, 34.0, 105.0, -86.0])   # wrist folded into the base (6 cm deep)
    assert cc.in_collision(folded)[0]
    assert any("iiwa_link_0" in a + b for a, b in cc.colliding_pairs(folded))


def test_environment_box_blocks(desc):
    wall = EnvironmentBox("wall", (0.1, 2.0, 2.0), (0.3, 0.0, 1.0))
    cc = CollisionChecker(desc, [wall])
    q = np.zeros(7)
    q[1] = np.radians(60.0)                               # lean forward into the wall at x = 0.3 m
    assert cc.in_collision(q)[0]
    assert any("env_wall" in a + b for a, b in cc.colliding_pairs(q))
    assert not cc.in_collision(np.zeros(7))[0]


def test_unvisited_by_distance():
    from scipy.spatial import cKDTree
    pts = np.array([[3.0, 0], [1.0, 0], [10.0, 0], [2.0, 0], [7.0, 0]])
    visited = np.array([False, False, False, True, False])
    assert list(unvisited_by_distance(cKDTree(pts), visited, np.zeros(2))) == [1, 0, 4, 2]


def test_scaffolds_in_nearest_neighbour_order(generated):
    path, _, _ = generated
    s = path.scaffolds
    assert path.reach_rejections == 0          # no reach collided for this seed: pure greedy NN order
    assert np.argmin(np.linalg.norm(s, axis=1)) == 0            # first: nearest to home (q = 0)
    for l in range(len(s) - 1):
        rest = np.linalg.norm(s[l + 1:] - s[l], axis=1)
        assert np.argmin(rest) == 0


def test_path_collision_free(desc, cfg, generated):
    _, timed, _ = generated
    _, q, _, _ = sample_trajectory(timed.trajectory, 20.0)
    assert not CollisionChecker(desc, cfg.boxes).in_collision(q).any()


def _write(tmp_path, mutate):
    from importlib import resources
    d = yaml.safe_load(resources.files("proprio.configs").joinpath("rfma.yaml").read_text())
    mutate(d)
    p = tmp_path / "rfma.yaml"
    p.write_text(yaml.safe_dump(d))
    return p


def test_bad_configs(tmp_path, desc):
    p = _write(tmp_path, lambda d: d["exploration"].update(amplitude_deg=[3.0, 0.5]))
    with pytest.raises(RfmaError, match=r"exploration\.amplitude_deg: inverted interval"):
        load_rfma_config(p)
    p = _write(tmp_path, lambda d: d["reach"].update(velocity_fraction=[0.9, 0.6]))
    with pytest.raises(RfmaError, match=r"reach\.velocity_fraction: inverted"):
        load_rfma_config(p)
    p = _write(tmp_path, lambda d: d.update(scaffolds=0))
    with pytest.raises(RfmaError, match="scaffolds"):
        load_rfma_config(p)
    p = _write(tmp_path, lambda d: d["workspace"].update(x_min_m=1.0))
    with pytest.raises(RfmaError, match="unreachable"):
        load_rfma_config(p)
    with pytest.raises(FileNotFoundError):
        load_rfma_config(tmp_path / "nope.yaml")


def test_unreachable_workspace_stops(desc):
    c = load_rfma_config(scaffolds=3, radius=0.05, max_tries=20000)
    with pytest.raises(RfmaError, match=r"unreachable workspace.*found 0 of 3 scaffolds after 20000 tries"):
        sample_scaffolds(desc, c, np.random.default_rng(0))


def test_not_enough_scaffolds_stops(desc):
    # a box filling the whole workspace: candidates reach the workspace but all collide
    c = load_rfma_config(scaffolds=3, max_tries=8192, boxes=(EnvironmentBox("block", (2.0, 2.0, 2.0), (1.0, 0, 1.0)),))
    with pytest.raises(RfmaError, match=r"found 0 of 3 scaffolds after 8192 tries"):
        sample_scaffolds(desc, c, np.random.default_rng(0))


def test_cli_rfma_and_plot(tmp_path, capsys):
    from proprio.cli import main
    from proprio.systems.trajectories import load_trajectory
    out = tmp_path / "r.npz"
    assert main(["trajectory", "rfma", "--scaffolds", "2", "--seed", "3", "--out", str(out)]) == 0
    traj, meta = load_trajectory(out)
    assert meta["source"] == "rfma" and meta["seed"] == 3 and len(meta["scaffolds"]) == 2
    assert meta["phase_kinds"] == ["reach", "explore", "reach", "explore", "reach"]
    png = tmp_path / "r.png"
    assert main(["trajectory", "plot", str(out), "--out", str(png)]) == 0
    assert png.stat().st_size > 10_000
    bad = _write(tmp_path, lambda d: d["exploration"].update(frequency=[4.0, -4.0]))
    assert main(["trajectory", "rfma", "--config", str(bad), "--out", str(tmp_path / "x.npz")]) == 2
    assert "exploration.frequency: inverted interval" in capsys.readouterr().err
    assert main(["trajectory", "plot", str(tmp_path / "missing.npz")]) == 2
