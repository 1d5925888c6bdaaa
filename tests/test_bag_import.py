"""``proprio import BAG``: ROS 2 bags (MCAP and sqlite3 folders, a single .mcap file) and ROS 1 .bag files written by
``rosbags``' own writers from the real LWR 4+ file and the imported TX40 log — joint names shuffled, a gripper joint,
a second JointState topic, a wrench topic, messages split by joint — imported back equal to the source; hostile bags
give one-line errors; the TX40 via its URDF with a ``drive:`` block identifies (and diagnoses) a drive-torque log."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from proprio.bag_import import JOINT_STATE, WRENCH_STAMPED, import_bag
from proprio.cli import main
from proprio.description import DescriptionError, load_robot
from proprio.importer import LogImportError, import_recording
from proprio.recording import Recording, load_recording, save_recording

rosbags = pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("PROPRIO_SHARED", REPO.parent / "shared"))
LWR_DIR = SHARED / "data" / "kuka_lwr4"
TX40_DIR = SHARED / "data" / "staubli_tx40"
TX40_URDF = TX40_DIR / "tx40_mdh_modified.urdf"
CONTAINERS = ("mcap", "sqlite3", "ros1")
SYNTH_ROBOT = "iiwa14_nominal"
T0_NS = 1_700_000_000_123_456_789          # a wall-clock epoch as a robot's clock gives it
TX40_DRIVE = {"tau_kind": "drive", "gear_ratio": [32.0, 32.0, 45.0, -48.0, 45.0, 32.0],
              "coupling": [[32, 0, 0, 0, 0, 0], [0, 32, 0, 0, 0, 0], [0, 0, 45, 0, 0, 0], [0, 0, 0, -48, 0, 0],
                           [0, 0, 0, 0, 45, 0], [0, 0, 0, 0, 32, 32]]}


def write_bag(path: Path, container: str, rec: Recording, names: list[str], *, split: bool = False,
              wrench: np.ndarray | None = None, zero_stamps: bool = False, seed: int = 0) -> Path:
    """Write ``rec`` as a bag with rosbags' own writer: ``/joint_states`` (the arm's joints in a shuffled order per
    message plus a gripper joint; ``split``: two messages per stamp, each with part of the joints), a second
    JointState topic ``/gripper/joint_states``, and ``/ft_sensor/wrench`` (WrenchStamped) when ``wrench [N, 6]`` is
    given. Receive times lag the header stamps by a random 0.1–2 ms (a FIFO transport: in order), so a reader that took
    them as the time base would miss the stamps by far more than 1 µs. ``zero_stamps``: messages without header
    stamps."""
    rng = np.random.default_rng(seed)
    ros1 = container == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    js, hdr, tm = (ts.types[k] for k in (JOINT_STATE, "std_msgs/msg/Header", "builtin_interfaces/msg/Time"))
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    stamps = T0_NS + np.round(rec.t * 1e9).astype(np.int64)
    recv = np.maximum.accumulate(stamps + rng.integers(100_000, 2_000_000, stamps.size))
    n = len(names)
    allnames = np.array(names + ["gripper_finger_joint"])

    def header(k: int, stamp: int):
        stamp = 0 if zero_stamps else int(stamp)
        return hdr(**({"seq": k} if ros1 else {}), stamp=tm(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="")

    if ros1:
        path = path.with_suffix(".bag")
        writer = Writer1(path)
    else:
        writer = Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP if container == "mcap"
                         else StoragePlugin.SQLITE3)
    with writer as w:
        c_js = w.add_connection("/joint_states", JOINT_STATE, typestore=ts)
        c_gr = w.add_connection("/gripper/joint_states", JOINT_STATE, typestore=ts)
        c_wr = w.add_connection("/ft_sensor/wrench", WRENCH_STAMPED, typestore=ts) if wrench is not None else None
        for k in range(rec.n_samples):
            perm = rng.permutation(n + 1)
            pos = np.append(rec.q[k], 0.02)[perm]
            eff = np.append(rec.tau[k], -1.5)[perm]
            vel = np.append(rec.qd[k], 0.0)[perm] if rec.qd is not None else np.empty(0)
            parts = np.array_split(np.arange(n + 1), 2) if split else [np.arange(n + 1)]
            for part in parts:
                msg = js(header=header(k, stamps[k]), name=allnames[perm][part].tolist(), position=pos[part],
                         velocity=vel[part] if vel.size else vel, effort=eff[part])
                w.write(c_js, int(recv[k]), serialize(msg, JOINT_STATE))
            if k % 10 == 0:
                gmsg = js(header=header(k, stamps[k]), name=["gripper_finger_joint"], position=np.array([0.02]),
                          velocity=np.empty(0), effort=np.array([-1.5]))
                w.write(c_gr, int(recv[k]), serialize(gmsg, JOINT_STATE))
            if c_wr is not None:
                v3 = ts.types["geometry_msgs/msg/Vector3"]
                wmsg = ts.types[WRENCH_STAMPED](header=hdr(**({"seq": k} if ros1 else {}),
                                                           stamp=tm(sec=int(stamps[k]) // 10**9,
                                                                    nanosec=int(stamps[k]) % 10**9), frame_id="tool0"),
                                                wrench=ts.types["geometry_msgs/msg/Wrench"](
                                                    force=v3(*wrench[k, :3]), torque=v3(*wrench[k, 3:])))
                w.write(c_wr, int(recv[k]), serialize(wmsg, WRENCH_STAMPED))
    return path


def assert_same(got: Recording, src: Recording) -> None:
    assert got.n_samples == src.n_samples
    np.testing.assert_allclose(got.t, src.t - src.t[0], rtol=0, atol=1e-6)          # stamps to 1 µs
    np.testing.assert_allclose(got.q, src.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.tau, src.tau, rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def lwr_slice() -> tuple[Recording, object]:
    if not LWR_DIR.exists():
        pytest.skip(f"real LWR 4+ data not found at {LWR_DIR}")
    robot = load_robot(LWR_DIR)
    rec = load_recording(LWR_DIR / "measurements_1.npz", robot)
    return rec.slice(1000, 1600), robot


@pytest.fixture(scope="module")
def synth() -> tuple[Recording, object]:
    """A smooth 7-joint motion of the shipped iiwa 14 (2 s at 100 Hz): the behaviour tests run without ../shared."""
    robot = load_robot(SYNTH_ROBOT)
    t = np.arange(200) * 0.01
    phase = np.linspace(0.0, 2.0, robot.n)
    q = 0.3 * np.sin(np.pi * t[:, None] + phase)
    return Recording(t=t, q=q, tau=5.0 * np.cos(np.pi * t[:, None] + phase), qd=0.3 * np.pi * np.cos(
        np.pi * t[:, None] + phase)), robot


@pytest.fixture(scope="module")
def tx40_rec() -> Recording:
    if not TX40_DIR.exists():
        pytest.skip(f"real TX40 data not found at {TX40_DIR}")
    return import_recording(REPO / "proprio" / "configs" / "import_tx40.yaml", data_dir=TX40_DIR)


@pytest.fixture(scope="module")
def tx40_robot(tmp_path_factory, tx40_rec) -> tuple[Path, object]:
    """The TX40 as a user with its URDF describes it: a proprio-urdf/v1 wrapper with a drive block."""
    path = tmp_path_factory.mktemp("tx40") / "tx40.yaml"
    path.write_text(yaml.safe_dump({"format": "proprio-urdf/v1", "name": "tx40_urdf", "urdf": str(TX40_URDF),
                                    "drive": TX40_DRIVE}))
    return path, load_robot(path)


@pytest.mark.parametrize("container", CONTAINERS)
def test_lwr4_in_every_container_imports_back_equal(tmp_path, lwr_slice, container):
    src, robot = lwr_slice
    names = list(robot.joint_names)
    bag = write_bag(tmp_path / "lwr", container, src, names, split=container != "mcap", seed=1)
    with pytest.raises(LogImportError, match="several sensor_msgs/msg/JointState topics.*/gripper/joint_states.*"
                                             "/joint_states.*--topic"):
        import_bag(bag, robot)
    got = import_bag(bag, robot, topic="/joint_states")
    assert_same(got, src)
    np.testing.assert_allclose(got.qd, src.qd, rtol=0, atol=1e-9)
    assert got.meta["import"]["time_base"] == "header" and got.meta["import"]["t0_ns"] == T0_NS + round(src.t[0] * 1e9)
    assert got.meta["tau_kind"] == "link_sensor"
    assert any("gripper_finger_joint" in note for note in got.meta["import"]["notes"])
    if container == "mcap":        # the single .mcap file of the folder reads the same
        assert_same(import_bag(next(bag.glob("*.mcap")), robot, topic="/joint_states"), src)


@pytest.mark.parametrize("container", CONTAINERS)
def test_tx40_in_every_container_through_the_cli(tmp_path, tx40_rec, tx40_robot, container, capsys):
    src = tx40_rec.slice(5000, 6500)                # 0.3 s at 5 kHz
    yaml_path, robot = tx40_robot
    names = list(robot.joint_names)
    wrench = np.random.default_rng(2).normal(0.0, 5.0, (src.n_samples, 6))
    bag = write_bag(tmp_path / "tx40", container, src, names, split=container == "ros1", wrench=wrench, seed=2)
    out = tmp_path / "tx40.npz"
    assert main(["import", str(bag), "--robot", str(yaml_path), "--topic", "/joint_states",
                 "--wrench-topic", "/ft_sensor/wrench", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "tau_kind drive" in printed and "note: /joint_states: joint(s) ['gripper_finger_joint']" in printed
    got = load_recording(out, robot)
    assert_same(got, src)
    np.testing.assert_allclose(got.f_ext, wrench, rtol=0, atol=1e-9)    # same stamps: the interpolation is exact
    assert got.meta["tau_kind"] == "drive" and got.meta["import"]["wrench_frame"] == "tool0"


def test_partial_messages_merge_by_stamp_and_receive_time_is_only_a_fallback(tmp_path, synth):
    src, robot = synth
    src = src.slice(0, 200)
    bag = write_bag(tmp_path / "nostamp", "mcap", src, list(robot.joint_names), split=True, zero_stamps=True)
    got = import_bag(bag, robot, topic="/joint_states")
    assert got.meta["import"]["time_base"] == "receive"
    assert any("receive times are the time base" in note for note in got.meta["import"]["notes"])
    np.testing.assert_allclose(got.q, src.q, rtol=0, atol=1e-9)
    assert 1e-6 < np.max(np.abs(got.t - (src.t - src.t[0]))) < 3e-3       # the transport's lag, not the stamps


def test_tau_kind_flag_and_description(tmp_path, synth):
    src, robot = synth
    bag = write_bag(tmp_path / "k", "mcap", src.slice(0, 50), list(robot.joint_names))
    assert import_bag(bag, robot, topic="/joint_states", tau_kind="drive").meta["tau_kind"] == "drive"
    with pytest.raises(LogImportError, match="tau_kind: must be one of"):
        import_bag(bag, robot, topic="/joint_states", tau_kind="current")


def _small(tmp_path, synth, container="mcap", **kw):
    src, robot = synth
    return write_bag(tmp_path / "b", container, src.slice(0, 40), list(robot.joint_names), **kw), robot, src


@pytest.mark.parametrize("args, message", [
    (["--topic", "/nope"], r"--topic /nope: no such topic; topics: /ft_sensor/wrench \(geometry_msgs/msg/WrenchStamped"),
    (["--topic", "/ft_sensor/wrench"], "--topic /ft_sensor/wrench: carries geometry_msgs/msg/WrenchStamped, not "
                                       "sensor_msgs/msg/JointState"),
    (["--topic", "/joint_states", "--wrench-topic", "/gripper/joint_states"],
     "--wrench-topic /gripper/joint_states: carries sensor_msgs/msg/JointState, not geometry_msgs/msg/WrenchStamped"),
    ([], "several sensor_msgs/msg/JointState topics"),
])
def test_hostile_topics_are_one_line_errors(tmp_path, synth, capsys, args, message):
    src, robot = synth
    bag = write_bag(tmp_path / "b", "mcap", src.slice(0, 20), list(robot.joint_names), wrench=np.zeros((20, 6)))
    out = tmp_path / "o.npz"
    assert main(["import", str(bag), "--robot", SYNTH_ROBOT, "--out", str(out), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("proprio: error:")
    import re
    assert re.search(message, err), err
    assert not out.exists()


def test_empty_topic_missing_joint_and_wrong_values(tmp_path, synth):
    src, robot = synth
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Writer2(tmp_path / "empty", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        w.add_connection("/joint_states", JOINT_STATE, typestore=ts)
    with pytest.raises(LogImportError, match="/joint_states: the topic has no messages"):
        import_bag(tmp_path / "empty", robot)
    short = src.slice(0, 30)
    bag = write_bag(tmp_path / "m", "mcap", short, ["other_joint"] + list(robot.joint_names[1:]))
    with pytest.raises(LogImportError, match=r"joint\(s\) \['iiwa_joint_1'\] of robot .* are in no message"):
        import_bag(bag, robot, topic="/joint_states")
    nan = Recording(t=short.t, q=short.q.copy(), tau=short.tau.copy(), qd=short.qd)
    nan.q[7, 2] = np.inf
    bag = write_bag(tmp_path / "n", "sqlite3", nan, list(robot.joint_names))
    with pytest.raises(LogImportError, match="message 7: joint 'iiwa_joint_3' position is inf"):
        import_bag(bag, robot, topic="/joint_states")
    nan.q[7, 2], nan.tau[9, 0] = 0.5, np.nan
    bag = write_bag(tmp_path / "nan", "ros1", nan, list(robot.joint_names))
    with pytest.raises(LogImportError, match="message 9: joint 'iiwa_joint_1' effort is nan"):
        import_bag(bag, robot, topic="/joint_states")
    deg = Recording(t=short.t, q=np.degrees(short.q) + 100.0, tau=short.tau, qd=short.qd)
    bag = write_bag(tmp_path / "d", "ros1", deg, list(robot.joint_names))
    with pytest.raises(ValueError, match="larger than 2π rad; q must be in radians"):
        import_bag(bag, robot, topic="/joint_states")


def test_backwards_and_repeated_stamps(tmp_path, synth):
    src, robot = synth
    short = src.slice(0, 30)
    t = short.t.copy()
    t[10] = t[8]                              # joint states stamped before the previous one
    bag = write_bag(tmp_path / "back", "mcap", Recording(t=t, q=short.q, tau=short.tau), list(robot.joint_names))
    with pytest.raises(LogImportError, match="header stamp of joint .* runs backwards at message 10"):
        import_bag(bag, robot, topic="/joint_states")
    t = short.t.copy()
    t[11] = t[10]                             # the same stamp twice: averaged and counted, as the CSV import does
    bag = write_bag(tmp_path / "dup", "mcap", Recording(t=t, q=short.q, tau=short.tau), list(robot.joint_names))
    got = import_bag(bag, robot, topic="/joint_states")
    assert got.n_samples == 29 and got.meta["duplicate_stamps"]["stamps"] == 1
    np.testing.assert_allclose(got.q[10], 0.5 * (short.q[10] + short.q[11]), atol=1e-12)


@pytest.mark.parametrize("container", CONTAINERS)
def test_truncated_and_foreign_files_are_one_line_errors(tmp_path, synth, capsys, container):
    bag, robot, _ = _small(tmp_path, synth, container)
    files = [bag] if bag.is_file() else [next(f for f in bag.iterdir() if f.suffix in (".mcap", ".db3"))]
    data = files[0].read_bytes()
    files[0].write_bytes(data[: len(data) // 2])
    target = bag if container != "mcap" else files[0]
    out = tmp_path / "o.npz"
    assert main(["import", str(target), "--robot", SYNTH_ROBOT, "--topic", "/joint_states", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("proprio: error:") and err.count("\n") == 0 and "cannot read the bag" in err, err
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    with pytest.raises(LogImportError, match="cannot read the bag"):
        import_bag(junk, robot)


def test_cli_refuses_what_a_bag_does_not_take(tmp_path, synth, capsys):
    bag, _, _ = _small(tmp_path, synth)
    out = str(tmp_path / "o.npz")
    assert main(["import", str(bag), "--out", out]) == 2
    assert "give --robot" in capsys.readouterr().err
    csv = tmp_path / "log.csv"
    csv.write_text("1,2\n")
    assert main(["import", str(csv), "--robot", SYNTH_ROBOT, "--out", out]) == 2
    assert "read through a mapping YAML" in capsys.readouterr().err


def test_urdf_wrapper_drive_block(tmp_path):
    if not TX40_URDF.exists():
        pytest.skip(f"TX40 URDF not found at {TX40_URDF}")
    base = {"format": "proprio-urdf/v1", "urdf": str(TX40_URDF)}
    path = tmp_path / "r.yaml"
    path.write_text(yaml.safe_dump({**base, "drive": TX40_DRIVE}))
    robot = load_robot(path)
    assert robot.drive.tau_kind == "drive" and robot.drive.coupled
    np.testing.assert_array_equal(robot.drive.coupling_matrix[5], [0, 0, 0, 0, 32, 32])
    assert load_robot(TX40_URDF).drive is None          # the URDF alone: link-side sensors, no drive
    path.write_text(yaml.safe_dump({**base, "drive": {"gear_ratio": TX40_DRIVE["gear_ratio"]}}))
    with pytest.raises(DescriptionError, match="drive.tau_kind: required"):
        load_robot(path)
    path.write_text(yaml.safe_dump({**base, "drive": {"tau_kind": "drive", "gear_ration": [1] * 6}}))
    with pytest.raises(DescriptionError, match="gear_ration"):
        load_robot(path)


def _validation_rmse(text: str) -> np.ndarray:
    """The per-joint RMSE column of ``identify``'s validation table [N·m]."""
    rows = text.split("validation:")[1].splitlines()
    return np.array([float(r.split()[-1]) for r in rows if r.split() and r.split()[0].isdigit()])


def test_tx40_urdf_with_drive_identifies_and_diagnoses_a_drive_torque_bag(tmp_path, tx40_rec, tx40_robot, capsys):
    """The URDF user's whole path: bag → import --tau-kind drive → identify → diagnose, with the TX40 described by its
    URDF and a drive block only. The coupled motor 6 lowers joint 5's held-out error as with the shipped YAML (README's
    TX40 table at 5 kHz: 5.22 → 1.08 N·m), and the diagnosis against the URDF's CAD inertials (no friction) puts
    friction first, as against the shipped staubli_tx40_cad."""
    yaml_path, robot = tx40_robot
    src = tx40_rec                                               # the whole 9 s: identification needs the motion
    dec = Recording(t=src.t[::5], q=src.q[::5], tau=src.tau[::5], meta=dict(src.meta))   # 1 kHz keeps it quick
    bag = write_bag(tmp_path / "tx40", "mcap", dec, list(robot.joint_names), seed=4)
    rec_path = tmp_path / "tx40.npz"
    assert main(["import", str(bag), "--robot", str(yaml_path), "--topic", "/joint_states", "--tau-kind", "drive",
                 "--out", str(rec_path)]) == 0
    capsys.readouterr()
    rmse = {}
    for flags, key in (([], "drive"), (["--no-drive", "--offsets"], "nodrive")):
        assert main(["identify", "--robot", str(yaml_path), "--train", str(rec_path), "--split-at", "6",
                     "--cutoff-hz", "100", *flags, "--out", str(tmp_path / f"{key}.npz")]) == 0
        rmse[key] = _validation_rmse(capsys.readouterr().out)
    assert rmse["drive"].shape == (6,)
    assert rmse["drive"][4] < 0.5 * rmse["nodrive"][4], rmse
    rec = load_recording(rec_path)
    i = int(np.searchsorted(rec.t, 6.0))
    save_recording(rec.slice(0, i), tmp_path / "tr.npz")
    save_recording(rec.slice(i, rec.n_samples), tmp_path / "ho.npz")
    assert main(["diagnose", "--model", str(yaml_path), "--train", str(tmp_path / "tr.npz"), "--holdout",
                 str(tmp_path / "ho.npz"), "--out", str(tmp_path / "diag")]) == 0
    import json
    result = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert result["robot"] == "tx40_urdf"
    assert result["ranking"][0]["name"] == "viscous_coulomb" and result["ranking"][0]["gain"] > 0.5, result["ranking"][0]


def test_stages_given_a_bag_say_how_to_convert_it(tmp_path, synth, capsys):
    bag, _, _ = _small(tmp_path, synth)
    for target in (bag, next(bag.glob("*.mcap"))):
        assert main(["inspect", str(target)]) == 2
        err = capsys.readouterr().err
        assert "a ROS bag, not a Recording (.npz); convert it with `proprio import" in err, err
