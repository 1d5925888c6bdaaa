"""``proprio view``: Meshcat playback of runs (diagrams/playback.py), its HTML export parsed back, the frame rule, the
visual geometry of the URDF export and the estimates file round trip."""
from __future__ import annotations

import base64
import dataclasses
import json
import re

import msgpack
import numpy as np
import pytest
from pydrake.geometry import Role
from pydrake.systems.framework import DiagramBuilder

from proprio.cli import main
from proprio.description import load_robot, rpy_to_matrix
from proprio.diagrams.playback import HEAD_LENGTH, POSITIVE_RGB, frame_groups
from proprio.dynamics import inverse_dynamics
from proprio.kinematics import flange_jacobian, flange_position
from proprio.plant import AddRobot
from proprio.recording import Recording, save_recording
from proprio.urdf import to_urdf, visual_shapes

RATE = 500.0
DURATION = 4.0
FORCE = np.array([15.0, -5.0, -9.81])        # constant force on the robot at the flange [N]
OFFSET_JOINT, OFFSET = 3, 3.0                 # a +3 N·m torque error on joint 4 after t = 2 s


def meshcat_commands(page: str) -> list[dict]:
    """The Meshcat commands a StaticHtml page replays (base64 msgpack blobs)."""
    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", page)
    return [msgpack.unpackb(base64.b64decode(b), raw=False, strict_map_key=False) for b in blobs]


def animation_tracks(page: str) -> dict[tuple[str, str], list[dict]]:
    """``(path, track name) → keys`` of the page's one animation."""
    anims = [c for c in meshcat_commands(page) if c["type"] == "set_animation"]
    assert len(anims) == 1
    return {(a["path"], tr["name"]): tr["keys"] for a in anims[0]["animations"] for tr in a["clip"]["tracks"]}


def rotations(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[K,3,3]`` of three.js quaternions ``[K,4]`` (x, y, z, w)."""
    x, y, z, w = quat.T
    return np.stack([np.column_stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
                     np.column_stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
                     np.column_stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])], axis=1)


@pytest.fixture(scope="module")
def pushed_run(tmp_path_factory):
    """A synthetic measured run of the nominal iiwa (no friction, so its own model explains τ exactly) pushed by a
    constant force at the flange, with a joint-4 torque error switched on halfway."""
    desc = load_robot("iiwa14_nominal")
    t = np.arange(0.0, DURATION, 1.0 / RATE)
    rng = np.random.default_rng(4)
    amp, freq, phase = rng.uniform(0.1, 0.3, 7), rng.uniform(0.1, 0.3, 7) * 2 * np.pi, rng.uniform(0, 6, 7)
    home = np.array([0.0, 0.6, 0.0, -1.2, 0.0, 0.9, 0.0])
    arg = freq * t[:, None] + phase
    q, qd, qdd = home + amp * np.sin(arg), amp * freq * np.cos(arg), -amp * freq ** 2 * np.sin(arg)
    wrench = np.tile(np.r_[FORCE, 0.0, 0.0, 0.0], (t.size, 1))
    tau_ext = np.einsum("nkj,nk->nj", flange_jacobian(desc, q)[:, 3:], wrench[:, :3])
    tau = inverse_dynamics(desc, q, qd, qdd) - tau_ext                   # τ_J = τ_rbd − Jᵀ f_ext
    tau[t >= DURATION / 2, OFFSET_JOINT] += OFFSET
    rec = Recording(t=t, q=q, tau=tau, f_ext=wrench, meta={"robot": desc.name, "source": "test_view"})
    return desc, rec, save_recording(rec, tmp_path_factory.mktemp("view") / "pushed.npz")


def test_view_html_has_every_frame_arrows_and_tints(pushed_run, tmp_path, capsys):
    desc, rec, path = pushed_run
    out = tmp_path / "out.html"
    assert main(["view", str(path), "--html", str(out), "--residual-scale", "2"]) == 0
    assert "frames" in capsys.readouterr().out
    page = out.read_text()
    tracks = animation_tracks(page)
    frames = frame_groups(rec.t, 30.0, 1800)
    k_all = list(range(frames.count))
    assert frames.count == round(rec.duration * 30) + 1
    # the arm: every body of the robot moves through every frame
    for link in desc.links:
        keys = tracks[(f"/drake/visualizer/{desc.name}/{link.name}", ".quaternion")]
        assert [k["time"] for k in keys] == k_all
    # the true force arrow: at the flange of the arm as drawn (the filtered q the observers used, within 10 µm of
    # the recorded q), along f, |f|·0.02 m long (shaft + head)
    f_true = [tracks[("/proprio/force_true", name)] for name in (".position", ".quaternion")]
    origin = np.array([k["value"] for k in f_true[0]])
    last = [tracks[(f"/drake/visualizer/{desc.name}/{desc.links[-1].name}", name)] for name in (".position",
                                                                                                 ".quaternion")]
    flange_drawn = np.array([k["value"] for k in last[0]]) + np.einsum(
        "nij,j->ni", rotations(np.array([k["value"] for k in last[1]])), desc.end_effector.xyz)
    np.testing.assert_allclose(origin, flange_drawn, atol=1e-9)
    np.testing.assert_allclose(origin, flange_position(desc, rec.q[frames.nearest]), atol=1e-5)
    z_axis = rotations(np.array([k["value"] for k in f_true[1]]))[:, :, 2]
    np.testing.assert_allclose(z_axis, np.tile(FORCE / np.linalg.norm(FORCE), (frames.count, 1)), atol=1e-9)
    shaft = np.array([k["value"][2] for k in tracks[("/proprio/force_true/shaft", ".scale")]])
    np.testing.assert_allclose(shaft + HEAD_LENGTH, 0.02 * np.linalg.norm(FORCE), rtol=1e-9)
    # the estimate (Jacobian observer) agrees with the truth away from the filter edges and the torque step
    est = [tracks[("/proprio/force_estimated", name)] for name in (".position", ".quaternion")]
    assert len(est[0]) == len(est[1]) == frames.count
    z_est = rotations(np.array([k["value"] for k in est[1]]))[:, :, 2]
    clean = (frames.times > 0.4) & (frames.times < 1.6)
    angle = np.degrees(np.arccos(np.clip(z_est[clean] @ (FORCE / np.linalg.norm(FORCE)), -1, 1)))
    assert angle.max() < 1.0
    # the links: joint 4's torque error tints link 4 red after the step, every link stays grey before it
    late = (frames.times > 2.5) & (frames.times < 3.5)
    for j, link in enumerate(desc.links):
        [color] = [v for (p, name), v in tracks.items() if name == ".material.color" and f"/{link.name}/" in p]
        rgb = np.array([k["value"] for k in color])
        assert rgb.shape == (frames.count, 3)
        assert np.abs(rgb[clean] - 0.8).max() < 0.05, link.name
        if j == OFFSET_JOINT:                                            # e = +3 N·m beyond the 2 N·m scale: red
            np.testing.assert_allclose(rgb[late], np.tile(POSITIVE_RGB, (late.sum(), 1)), atol=1e-6)
        else:
            assert np.abs(rgb[late] - 0.8).max() < 0.05, link.name
    summary = json.loads(re.search(r"id='proprio-playback'>(.*?)</script>", page).group(1))
    assert summary["frames"] == frames.count and summary["samples"] == rec.n_samples
    assert set(summary["arrows"]) == {"estimated", "true"} and summary["residual_scale_Nm"] == 2.0
    assert "proprio-legend" in page and "http://" not in page.split("<script")[0]


def test_long_runs_are_capped_and_windowed(pushed_run, tmp_path, capsys):
    _, rec, path = pushed_run
    out = tmp_path / "short.html"
    assert main(["view", str(path), "--html", str(out), "--max-frames", "40", "--start", "1", "--end", "3",
                 "--fps", "25"]) == 0
    assert "×1.28 real time" in capsys.readouterr().out        # 2 s in 40 frames at 25 fps
    tracks = animation_tracks(out.read_text())
    # one key per frame on every track (at 25 fps, frame 29's time 29/25 s would floor to frame 28 if it were
    # recorded at exactly k/fps)
    for keys in tracks.values():
        assert [k["time"] for k in keys] == list(range(40))


def test_frame_groups_partition_every_sample():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.004, 0.006, 120_000))              # 10 min of a jittered 200 Hz log
    t[50_000:] += 2.0                                              # and a 2 s gap: empty groups
    fr = frame_groups(t, fps=30.0, max_frames=1800)
    assert fr.count == 1800 and fr.period == pytest.approx((t[-1] - t[0]) / 1799)
    assert fr.speedup == pytest.approx(fr.period * 30.0)
    assert fr.bounds[0] == 0 and fr.bounds[-1] == t.size and np.all(np.diff(fr.bounds) >= 0)
    group = np.repeat(np.arange(fr.count), np.diff(fr.bounds))    # every sample in exactly one group...
    assert np.all(np.abs(t - fr.times[group]) <= fr.period / 2 + 1e-9)  # ...the one whose frame time is nearest
    for k in rng.choice(fr.count, 50, replace=False):
        assert fr.nearest[k] == np.argmin(np.abs(t - fr.times[k]))
    x = rng.normal(size=(t.size, 2))
    mean = fr.mean(x)
    for k in rng.choice(fr.count, 50, replace=False):
        lo, hi = fr.bounds[k], fr.bounds[k + 1]
        np.testing.assert_allclose(mean[k], x[lo:hi].mean(axis=0) if hi > lo else x[fr.nearest[k]], atol=1e-9)
    assert (np.diff(fr.bounds) == 0).sum() > 0                     # the gap's frames show the nearest sample
    short = frame_groups(np.arange(0.0, 2.0, 0.001), fps=30.0, max_frames=1800)
    assert short.count == 61 and short.speedup == pytest.approx(1.0)


def test_view_of_an_estimates_file(pushed_run, tmp_path, capsys):
    desc, rec, path = pushed_run
    assert main(["estimate", "--model", desc.name, "--recording", str(path), "--out", str(tmp_path / "est")]) == 0
    capsys.readouterr()
    out = tmp_path / "est.html"
    assert main(["view", str(tmp_path / "est"), "--html", str(out), "--observer", "momentum"]) == 0
    tracks = animation_tracks(out.read_text())
    n_frames = frame_groups(rec.t).count
    assert len(tracks[("/proprio/force_estimated", ".position")]) == n_frames
    assert len(tracks[("/proprio/force_true", ".position")]) == n_frames


def test_view_shows_the_estimation_diagrams_numbers(pushed_run):
    """One estimator law: the playback of a Recording (what ``proprio view`` draws) carries exactly the estimation
    diagram's estimates (``proprio estimate``) — a second copy of the observers on the view path would differ — and
    the vectorised form of the same law gives them too, sample for sample."""
    from proprio.diagrams.estimation import estimate_wrench, estimate_wrench_offline
    from proprio.diagrams.playback import playback_from_recording, torque_residual

    desc, rec, _ = pushed_run
    res, off = estimate_wrench(desc, rec), estimate_wrench_offline(desc, rec)
    before_error = res.valid() & (res.t < 0.45 * DURATION)                     # a real push, seen by both observers
    for observer in ("jacobian", "momentum"):
        assert np.abs(res.wrench[observer][before_error, :3] - FORCE).max() < 0.5, observer
    for observer in ("jacobian", "momentum"):
        pb = playback_from_recording(rec, desc, observer)
        np.testing.assert_allclose(pb.f_est, res.wrench[observer][:, :3], rtol=0, atol=1e-10)
        np.testing.assert_allclose(pb.residual, torque_residual(res, desc, observer), rtol=0, atol=1e-10)
        np.testing.assert_allclose(off.wrench[observer], res.wrench[observer], rtol=1e-10, atol=1e-9)   # 15 N forces: relative 1e-10


def test_view_errors_are_one_line(pushed_run, tmp_path, capsys):
    _, rec, _ = pushed_run
    odd = save_recording(rec.replace(meta={"robot": "no_such_arm"}), tmp_path / "odd.npz")
    assert main(["view", str(odd), "--html", str(tmp_path / "x.html")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("proprio: error:") and "--model" in err and len(err.strip().splitlines()) == 1
    assert main(["view", str(odd), "--model", "iiwa14_nominal", "--fps", "0"]) == 2
    assert "--fps" in capsys.readouterr().err
    assert main(["view", str(odd), "--model", "iiwa14_nominal", "--start", "10", "--html",
                 str(tmp_path / "y.html")]) == 2
    assert "window" in capsys.readouterr().err
    assert main(["view", str(tmp_path / "missing.npz")]) == 2
    assert not (tmp_path / "x.html").exists()


def test_live_view_serves_on_localhost(pushed_run, capsys):
    _, _, path = pushed_run
    assert main(["view", str(path), "--end", "1", "--port", "0", "--serve-seconds", "0"]) == 0
    assert re.search(r"Meshcat: http://localhost:\d+", capsys.readouterr().out)


def test_visual_geometry_of_the_urdf_export(iiwa):
    assert "<visual" not in to_urdf(iiwa)                          # the default export is unchanged
    bare = dataclasses.replace(iiwa, links=tuple(dataclasses.replace(lk, collision=()) for lk in iiwa.links))
    shapes = visual_shapes(bare)
    tips = [j.origin_xyz for j in bare.joints[1:]] + [bare.end_effector.xyz]
    for link, joint, tip in zip(bare.links, bare.joints, tips):
        hub, *segment = shapes[link.name]
        np.testing.assert_allclose(rpy_to_matrix(hub.rpy)[:, 2], joint.axis, atol=1e-12)
        if np.linalg.norm(tip) > 1e-3:                              # a stick from the link origin to the next joint
            [seg] = segment
            np.testing.assert_allclose(rpy_to_matrix(seg.rpy)[:, 2] * seg.length, tip, atol=1e-12)
            np.testing.assert_allclose(np.multiply(seg.xyz, 2), tip, atol=1e-12)
    assert visual_shapes(iiwa)[iiwa.links[0].name] == iiwa.links[0].collision   # collision primitives are reused
    for desc in (iiwa, bare):
        robot = AddRobot(DiagramBuilder(), desc, visual=True)
        inspector = robot.scene_graph.model_inspector()
        for link in desc.links:
            frame = robot.plant.GetBodyFrameIdOrThrow(robot.plant.GetBodyByName(link.name).index())
            assert len(inspector.GetGeometries(frame, Role.kIllustration)) == len(visual_shapes(desc)[link.name]) > 0
