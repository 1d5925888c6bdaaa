"""Robot descriptions: the validating YAML loader, shipped iiwa models (thesis Table 2.3), MDH and URDF import."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import yaml

from proprio.description import (DescriptionError, Link, builtin_robots, load_robot, robot_from_dict, robot_from_mdh,
                                 robot_from_urdf)
from proprio.dynamics import inverse_dynamics
from proprio.kinematics import flange_pose, link_poses
from proprio.urdf import to_urdf

# thesis Table 2.3 (KUKA LBR iiwa 14 R820): position range ±deg, velocity range ±deg/s
TABLE_2_3_POS_DEG = [170, 120, 170, 120, 170, 120, 175]
TABLE_2_3_VEL_DEG_S = [85, 85, 100, 75, 130, 135, 135]
# thesis Table 2.2 (modified DH). Its header row is shuffled; the physically meaningful reading is:
MDH_ALPHA_DEG = [0, -90, 90, 90, -90, -90, 90]
MDH_A = [0.0] * 7
MDH_D = [0.36, 0.0, 0.42, 0.0, 0.4, 0.0, 0.126]


def iiwa_dict() -> dict:
    return yaml.safe_load(resources.files("proprio.robots").joinpath("iiwa14_identified.yaml").read_text())


def mdh_product(q: np.ndarray, alpha: list[float], a: list[float], d: list[float],
                offset: list[float] | None = None) -> np.ndarray:
    """Craig's modified DH: T = Π Rx(α_i) Tx(a_i) Rz(θ_i) Tz(d_i), written out as one matrix per joint."""
    t = np.eye(4)
    off = offset or [0.0] * len(alpha)
    for al, ai, di, qi, oi in zip(alpha, a, d, q, off):
        ca, sa, c, s = math.cos(al), math.sin(al), math.cos(qi + oi), math.sin(qi + oi)
        t = t @ np.array([[c, -s, 0.0, ai], [s * ca, c * ca, -sa, -sa * di], [s * sa, c * sa, ca, ca * di],
                          [0.0, 0.0, 0.0, 1.0]])
    return t


# ---- loader validation: every error names the offending field ---------------------------------------------------

def _expect(data: dict, *fragments: str) -> None:
    with pytest.raises(DescriptionError) as info:
        robot_from_dict(data, "robot.yaml")
    msg = str(info.value)
    assert "\n" not in msg
    for f in fragments:
        assert f in msg, f"{f!r} not in {msg!r}"


def test_builtin_robots_listed():
    assert {"iiwa14_identified", "iiwa14_nominal"} <= set(builtin_robots())


def test_missing_mass_names_link_and_field():
    d = iiwa_dict()
    del d["links"][2]["mass"]
    _expect(d, "links[2]", "iiwa_link_3", "'mass'")


def test_negative_mass_rejected():
    d = iiwa_dict()
    d["links"][0]["mass"] = -1.0
    _expect(d, "links[0]", "mass", ">= 0")


def test_non_unit_axis():
    d = iiwa_dict()
    d["joints"][3]["axis"] = [0.0, 0.0, 2.0]
    _expect(d, "joints[3]", "iiwa_joint_4", "axis", "unit vector")


def test_axis_wrong_length():
    d = iiwa_dict()
    d["joints"][1]["axis"] = [0.0, 1.0]
    _expect(d, "joints[1]", "axis", "expected 3 numbers")


def test_inverted_limits():
    d = iiwa_dict()
    d["joints"][0]["limits"].update(lower_deg=170, upper_deg=-170)
    _expect(d, "joints[0]", "limits", "lower", "upper")


def test_degree_limits_without_deg_suffix():
    d = iiwa_dict()
    lim = d["joints"][5]["limits"]
    del lim["lower_deg"], lim["upper_deg"]
    lim.update(lower=-120, upper=120)
    _expect(d, "joints[5]", "limits", "_deg")


def test_degree_velocity_without_deg_suffix():
    d = iiwa_dict()
    lim = d["joints"][3]["limits"]
    del lim["velocity_deg"]
    lim["velocity"] = 75
    _expect(d, "joints[3]", "velocity", "_deg")


def test_both_rad_and_deg_keys_rejected():
    d = iiwa_dict()
    d["joints"][1]["limits"]["lower"] = -2.0
    _expect(d, "joints[1]", "lower", "lower_deg")


def test_missing_limits_mapping():
    d = iiwa_dict()
    del d["joints"][2]["limits"]
    _expect(d, "joints[2]", "limits")


def test_deg_keys_converted():
    d = iiwa_dict()
    d["joints"][0]["limits"] = {"lower_deg": -90, "upper_deg": 45, "velocity_deg": 180, "effort": 10.0}
    desc = robot_from_dict(d)
    assert desc.joints[0].lower == pytest.approx(-math.pi / 2, abs=1e-15)
    assert desc.joints[0].upper == pytest.approx(math.pi / 4, abs=1e-15)
    assert desc.joints[0].velocity == pytest.approx(math.pi, abs=1e-15)


def test_inertia_not_psd():
    d = iiwa_dict()
    d["links"][4]["inertia_com"]["ixx"] = -0.01
    _expect(d, "links[4]", "inertia_com", "positive semi-definite")


def test_inertia_triangle_inequality():
    d = iiwa_dict()
    d["links"][1]["inertia_com"] = {"ixx": 0.01, "iyy": 0.01, "izz": 0.05, "ixy": 0.0, "ixz": 0.0, "iyz": 0.0}
    _expect(d, "links[1]", "inertia_com", "triangle")


def test_inertia_missing_moment():
    d = iiwa_dict()
    del d["links"][6]["inertia_com"]["izz"]
    _expect(d, "links[6]", "inertia_com", "izz")


def test_bad_collision_shape():
    d = iiwa_dict()
    d["links"][0]["collision"] = [{"shape": "torus", "radius": 0.1}]
    _expect(d, "links[0]", "collision[0]", "torus")


def test_friction_length_and_sign():
    d = iiwa_dict()
    d["friction"]["viscous"] = [0.1] * 6
    _expect(d, "friction", "viscous", "7")
    d = iiwa_dict()
    d["friction"]["coulomb"][3] = -0.1
    _expect(d, "friction", ">= 0")


def test_chain_must_be_serial():
    d = iiwa_dict()
    d["joints"][4]["parent"] = "iiwa_link_1"
    _expect(d, "joints[4]", "parent", "serial")


def test_joint_link_count_mismatch():
    d = iiwa_dict()
    d["links"].pop()
    _expect(d, "7 joints but 6 links")


def test_bad_yaml_file(tmp_path):
    p = tmp_path / "broken.yaml"
    p.write_text("name: x\njoints: [\n  - {name: a\n")
    with pytest.raises(DescriptionError, match="invalid YAML"):
        load_robot(p)


def test_top_level_not_mapping(tmp_path):
    p = tmp_path / "list.yaml"
    p.write_text("- 1\n- 2\n")
    with pytest.raises(DescriptionError, match="top level must be a mapping"):
        load_robot(p)


def test_unknown_robot_name():
    with pytest.raises(DescriptionError, match="unknown robot 'iiwa99'"):
        load_robot("iiwa99")


def test_to_dict_round_trip():
    for name in builtin_robots():
        desc = load_robot(name)
        assert robot_from_dict(desc.to_dict(), name) == desc


# ---- shipped iiwa models ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["iiwa14_identified", "iiwa14_nominal"])
def test_iiwa_limits_equal_table_2_3(name):
    desc = load_robot(name)
    assert desc.n == 7
    np.testing.assert_allclose(desc.upper, np.radians(TABLE_2_3_POS_DEG), rtol=0, atol=1e-15)
    np.testing.assert_allclose(desc.lower, -np.radians(TABLE_2_3_POS_DEG), rtol=0, atol=1e-15)
    np.testing.assert_allclose(desc.velocity_limits, np.radians(TABLE_2_3_VEL_DEG_S), rtol=0, atol=1e-15)
    assert np.all(desc.effort_limits > 0)
    assert desc.provenance  # each shipped file states where its numbers come from


def test_identified_has_friction_nominal_not():
    ident, nominal = load_robot("iiwa14_identified"), load_robot("iiwa14_nominal")
    assert ident.has_friction and not nominal.has_friction
    # DESIGN.md: Coulomb 0.03–0.32 N·m, viscous 0.10–0.37 N·m·s/rad
    assert 0.03 <= min(ident.friction_coulomb) and max(ident.friction_coulomb) <= 0.32
    assert 0.10 <= min(ident.friction_viscous) and max(ident.friction_viscous) <= 0.38
    # the two sets differ in their inertials, not in their kinematics
    q = np.random.default_rng(3).uniform(-1, 1, (5, 7))
    np.testing.assert_allclose(flange_pose(ident, q), flange_pose(nominal, q), atol=1e-12)
    assert not np.allclose(inverse_dynamics(ident, q, q, q), inverse_dynamics(nominal, q, q, q))


# ---- modified-DH import (thesis Table 2.2) -------------------------------------------------------------------------

def test_mdh_table_2_2_matches_iiwa_kinematics():
    mdh = robot_from_mdh(np.radians(MDH_ALPHA_DEG).tolist(), MDH_A, MDH_D)
    iiwa = load_robot("iiwa14_identified")
    q = np.random.default_rng(0).uniform(iiwa.lower, iiwa.upper, (50, 7))
    np.testing.assert_allclose(flange_pose(mdh, np.zeros(7))[:3, 3], [0.0, 0.0, 1.306], atol=1e-12)
    # the MDH frames and the iiwa URDF frames agree up to constant base and flange rotations (identity here)
    c = np.linalg.inv(flange_pose(mdh, np.zeros(7))) @ flange_pose(iiwa, np.zeros(7))
    np.testing.assert_allclose(flange_pose(mdh, q) @ c, flange_pose(iiwa, q), atol=1e-12)


def test_mdh_description_equals_mdh_product_with_offsets():
    rng = np.random.default_rng(1)
    alpha, a, d, off = (rng.uniform(-2, 2, 5).tolist() for _ in range(4))
    desc = robot_from_mdh(alpha, a, d, theta_offset=off)
    for q in rng.uniform(-3, 3, (20, 5)):
        np.testing.assert_allclose(flange_pose(desc, q), mdh_product(q, alpha, a, d, off), atol=1e-12)


def test_mdh_yaml_format(tmp_path):
    p = tmp_path / "iiwa_mdh.yaml"
    p.write_text(yaml.safe_dump({
        "format": "proprio-mdh/v1", "name": "iiwa_mdh",
        "mdh": {"alpha_deg": MDH_ALPHA_DEG, "a": MDH_A, "d": MDH_D},
        "limits": {"position_deg": TABLE_2_3_POS_DEG, "velocity_deg_s": TABLE_2_3_VEL_DEG_S},
    }))
    desc = load_robot(p)
    assert desc.name == "iiwa_mdh" and desc.n == 7
    np.testing.assert_allclose(desc.upper, np.radians(TABLE_2_3_POS_DEG), atol=1e-15)
    np.testing.assert_allclose(desc.velocity_limits, np.radians(TABLE_2_3_VEL_DEG_S), atol=1e-15)
    np.testing.assert_allclose(flange_pose(desc, np.zeros(7))[:3, 3], [0, 0, 1.306], atol=1e-12)


def test_mdh_table_length_mismatch():
    with pytest.raises(DescriptionError, match="alpha, a, d"):
        robot_from_mdh([0.0, 1.0], [0.0], [0.0, 0.0])


# ---- URDF import ----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["iiwa14_identified", "iiwa14_nominal"])
def test_urdf_round_trip_gives_identical_dynamics(tmp_path, name):
    desc = load_robot(name)
    p = tmp_path / f"{name}.urdf"
    p.write_text(to_urdf(desc, world_joint=False))
    back = load_robot(p)  # dispatches on the .urdf suffix
    assert back.joint_names == desc.joint_names
    np.testing.assert_allclose(back.lower, desc.lower, rtol=0, atol=0)
    np.testing.assert_allclose(back.velocity_limits, desc.velocity_limits, rtol=0, atol=0)
    rng = np.random.default_rng(2)
    q, qd, qdd = (rng.uniform(-2, 2, (30, 7)) for _ in range(3))
    np.testing.assert_allclose(inverse_dynamics(back, q, qd, qdd), inverse_dynamics(desc, q, qd, qdd),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(link_poses(back, q), link_poses(desc, q), rtol=0, atol=1e-12)


def test_urdf_round_trip_keeps_base_pose_and_flange(tmp_path):
    desc = dataclasses.replace(load_robot("iiwa14_identified"), world_to_base_xyz=(0.1, -0.2, 0.5),
                               world_to_base_rpy=(0.3, -0.2, 0.7))
    p = tmp_path / "with_world.urdf"
    p.write_text(to_urdf(desc))  # base welded to a 'world' link, flange as a fixed frame link
    back = robot_from_urdf(p)
    assert back.base.name == desc.base.name and back.end_effector.name == "flange"
    np.testing.assert_allclose(back.world_to_base_xyz, desc.world_to_base_xyz, atol=1e-15)
    q = np.random.default_rng(4).uniform(-1, 1, (20, 7))
    np.testing.assert_allclose(flange_pose(back, q), flange_pose(desc, q), rtol=0, atol=1e-12)
    np.testing.assert_allclose(inverse_dynamics(back, q, q, q), inverse_dynamics(desc, q, q, q), atol=1e-12)
    offset = robot_from_urdf(p, flange_xyz=(0.0, 0.0, 0.1))  # a tool 10 cm along the flange z axis
    np.testing.assert_allclose(flange_pose(offset, q)[:, :3, 3],
                               flange_pose(desc, q)[:, :3, 3] + 0.1 * flange_pose(desc, q)[:, :3, 2], atol=1e-12)


def test_urdf_import_of_drakes_acrobot_matches_drake():
    """A third-party URDF (shipped with the drake wheel): base welded to an undeclared 'world', continuous joints."""
    from pydrake.common import FindResourceOrThrow
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.multibody.tree import MultibodyForces

    path = FindResourceOrThrow("drake/examples/acrobot/Acrobot.urdf")
    desc = robot_from_urdf(path)
    assert desc.joint_names == ["shoulder", "elbow"] and desc.base.name == "base_link"
    plant = MultibodyPlant(0.0)
    Parser(plant).AddModels(path)
    plant.Finalize()
    ctx = plant.CreateDefaultContext()
    rng = np.random.default_rng(5)
    q, qd, qdd = (rng.uniform(-2, 2, (10, 2)) for _ in range(3))
    tau = inverse_dynamics(desc, q, qd, qdd)
    for k in range(10):
        plant.SetPositions(ctx, q[k])
        plant.SetVelocities(ctx, qd[k])
        forces = MultibodyForces(plant)
        plant.CalcForceElementsContribution(ctx, forces)
        # Drake adds the URDF's <dynamics damping="0.1"/> (not imported: friction is not read from URDF)
        drake_tau = plant.CalcInverseDynamics(ctx, qdd[k], forces) - 0.1 * qd[k]
        np.testing.assert_allclose(tau[k], drake_tau, rtol=0, atol=1e-10)


def test_urdf_needs_revolute_joints(tmp_path):
    p = tmp_path / "two_roots.urdf"
    p.write_text("<robot name='r'><link name='a'/><link name='b'/></robot>")
    with pytest.raises(DescriptionError, match="no revolute joints"):
        load_robot(p)


def test_urdf_not_xml(tmp_path):
    p = tmp_path / "bad.urdf"
    p.write_text("<robot name='x'><link name='a'>")
    with pytest.raises(DescriptionError, match="not valid XML"):
        load_robot(p)


def test_urdf_prismatic_rejected(tmp_path):
    p = tmp_path / "prismatic.urdf"
    p.write_text("<robot name='r'><link name='a'/><link name='b'/><joint name='slide' type='prismatic'>"
                 "<parent link='a'/><child link='b'/><axis xyz='1 0 0'/></joint></robot>")
    with pytest.raises(DescriptionError, match="slide.*prismatic"):
        load_robot(p)


# ---- the real LWR 4+ description -------------------------------------------------------------------------------------

def test_lwr_robot_yaml_loads(lwr_dir):
    desc = load_robot(lwr_dir)
    assert desc.name == "kuka_lwr4plus" and desc.n == 7
    assert desc.joint_names == [f"lwr_{i}_joint" for i in range(7)]
    assert desc.world_to_base_xyz == (0.0, 0.0, 1.0)
    np.testing.assert_allclose([j.axis for j in desc.joints],
                               [[0, 0, 1], [0, -1, 0], [0, 0, 1], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, 1]])
    np.testing.assert_allclose(desc.upper, np.radians([170, 120, 170, 120, 170, 120, 170]), atol=1e-10)
    assert desc.end_effector.parent == "lwr_7_link"
    assert not desc.has_friction
    assert sum(lk.mass for lk in desc.links) == pytest.approx(12.4 - 2.0)  # 12.4 kg incl. the 2 kg base


def test_with_inertials_checks_count():
    desc = load_robot("iiwa14_nominal")
    with pytest.raises(DescriptionError, match="expected 7 links"):
        desc.with_inertials([Link("x", 1.0, (0, 0, 0), (1e-3, 1e-3, 1e-3, 0, 0, 0))])


def test_readme_yaml_example_loads():
    """The two-link example of the docs (guide/robots.md) is a valid description (keeps the docs honest)."""
    readme = Path(__file__).resolve().parents[1] / "docs" / "guide" / "robots.md"
    if not readme.exists():
        pytest.skip("docs/guide/robots.md not found")
    block = re.search(r"```yaml\n(format: proprio-robot/v1.*?)```", readme.read_text(), re.S)
    assert block, "docs/guide/robots.md lost its proprio-robot/v1 example"
    desc = robot_from_dict(yaml.safe_load(block.group(1)), "README example")
    assert desc.n == 2 and desc.has_friction and desc.joints[0].upper == pytest.approx(math.radians(170))
    assert desc.links[1].collision[0].shape == "cylinder"


@pytest.mark.parametrize("data, fragment", [
    ({"format": "proprio-mdh/v1", "mdh": {"alpha_deg": [0, 90], "a": [0, 0]}}, "mdh: missing field 'd'"),
    ({"format": "proprio-mdh/v1", "mdh": {"a": [0, 0], "d": [0, 0]}}, "missing field 'alpha_deg'"),
    ({"format": "proprio-mdh/v1", "mdh": {"alpha_deg": [0, 90], "a": [0, 0], "d": [0.1, 0]},
      "limits": {"position_deg": [170]}}, "limits.position_deg: expected 2 numbers, got 1"),
    ({"base": [1, 2], "joints": [], "links": []}, "base: expected a mapping"),
])
def test_malformed_sections_name_the_field(data, fragment):
    _expect(data, fragment)


def test_end_effector_must_be_mapping():
    d = iiwa_dict()
    d["end_effector"] = "flange"
    _expect(d, "end_effector", "mapping")


# ---- URDFs as the ROS ecosystem writes them ----------------------------------------------------------------------

def _inertial(m: float, xyz: str, rpy: str, i: tuple[float, ...]) -> str:
    return (f"<inertial><mass value='{m}'/><origin xyz='{xyz}' rpy='{rpy}'/><inertia ixx='{i[0]}' iyy='{i[1]}' "
            f"izz='{i[2]}' ixy='{i[3]}' ixz='{i[4]}' iyz='{i[5]}'/></inertial>")


def _joint(name: str, kind: str, parent: str, child: str, xyz: str, rpy: str = "0 0 0", axis: str = "0 0 1") -> str:
    lim = "<limit lower='-3' upper='3' effort='150' velocity='3'/>" if kind == "revolute" else ""
    ax = f"<axis xyz='{axis}'/>" if kind == "revolute" else ""
    return (f"<joint name='{name}' type='{kind}'><parent link='{parent}'/><child link='{child}'/>"
            f"<origin xyz='{xyz}' rpy='{rpy}'/>{ax}{lim}</joint>")


def ros_industrial_urdf(gripper: bool = False) -> str:
    """A UR-style arm: world weld (tilted mount), base_link with 'base' and 'base_link_inertia' frames (rotated by π
    like ROS-Industrial's), a massive sensor frame between two joints, flange and tool0 (with a tool's mass) at the
    tip; optionally a two-finger gripper (two more revolute joints: a branching tree)."""
    bodies = [("base_link_inertia", 4.0, "0 0 0.05", "0 0 0", (0.01, 0.01, 0.008, 0, 0, 0)),
              ("shoulder_link", 3.7, "0 0.01 0", "0 0 0", (0.015, 0.014, 0.01, 0, 0, 0.001)),
              ("upper_arm_link", 8.4, "-0.2 0 0.14", "0 1.5707963 0", (0.13, 0.13, 0.015, 0, 0, 0)),
              ("forearm_link", 2.3, "-0.19 0 0.03", "0.1 0.2 0.3", (0.05, 0.049, 0.004, 0.001, 0, 0)),
              ("ft_sensor", 0.6, "0.01 0 0.02", "0 0 0", (0.0005, 0.0005, 0.0008, 0, 0, 0)),
              ("wrist_1_link", 1.2, "0 0.01 0.02", "0 0 0", (0.002, 0.0018, 0.0015, 0, 0, 0)),
              ("tool0", 0.4, "0 0 0.05", "0 0 0", (0.0006, 0.0006, 0.0003, 0, 0, 0))]
    if gripper:
        bodies += [(f"{side}_finger", 0.05, "0 0 0.02", "0 0 0", (1e-5, 1e-5, 1e-5, 0, 0, 0)) for side in ("l", "r")]
    links = ["<link name='world'/>", "<link name='base_link'/>", "<link name='base'/>", "<link name='flange'/>"]
    links += [f"<link name='{name}'>{_inertial(*rest)}</link>" for name, *rest in bodies]
    joints = [_joint("world_joint", "fixed", "world", "base_link", "0.1 -0.2 0.8", "0.05 -0.1 0.3"),
              _joint("base_link-base_fixed_joint", "fixed", "base_link", "base", "0 0 0", "0 0 3.14159265359"),
              _joint("base_link-base_link_inertia", "fixed", "base_link", "base_link_inertia", "0 0 0",
                     "0 0 3.14159265359"),
              _joint("shoulder_pan_joint", "revolute", "base_link_inertia", "shoulder_link", "0 0 0.1625"),
              _joint("shoulder_lift_joint", "revolute", "shoulder_link", "upper_arm_link", "0 0 0", "1.570796327 0 0"),
              _joint("elbow_joint", "revolute", "upper_arm_link", "forearm_link", "-0.425 0 0"),
              _joint("forearm-ft_sensor", "fixed", "forearm_link", "ft_sensor", "-0.3922 0 0.05", "0 0.2 0"),
              _joint("wrist_1_joint", "revolute", "ft_sensor", "wrist_1_link", "0 0 0.08", "0 0 0", "0 1 0"),
              _joint("wrist_1-flange", "fixed", "wrist_1_link", "flange", "0 0.1 0", "0 0 -1.5707963"),
              _joint("flange-tool0", "fixed", "flange", "tool0", "0 0 0.02", "1.5707963 0 1.5707963")]
    if gripper:
        joints += [_joint(f"{side}_finger_joint", "revolute", "tool0", f"{side}_finger", "0 0 0.03") for side in "lr"]
    return "<?xml version='1.0'?><robot name='ur_like'>" + "".join(links + joints) + "</robot>"


def test_ros_industrial_urdf_loads_as_is_and_matches_drake(tmp_path):
    """Extra fixed frames load unchanged; the chain's dynamics (fixed links lumped onto their bodies) equal Drake's
    CalcInverseDynamics on a plant parsed from the full URDF, and the flange is Drake's tool0 frame."""
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.multibody.tree import MultibodyForces

    path = tmp_path / "ur_like.urdf"
    path.write_text(ros_industrial_urdf())
    desc = load_robot(path)
    assert desc.joint_names == ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint"]
    assert desc.base.name == "base_link_inertia" and desc.end_effector.name == "tool0"
    assert desc.links[2].mass == pytest.approx(2.3 + 0.6) and desc.links[3].mass == pytest.approx(1.2 + 0.4)
    plant = MultibodyPlant(0.0)
    Parser(plant).AddModelsFromString(path.read_text(), "urdf")
    plant.Finalize()
    ctx = plant.CreateDefaultContext()
    rng = np.random.default_rng(11)
    q, qd, qdd = (rng.uniform(-2, 2, (12, 4)) for _ in range(3))
    tau = inverse_dynamics(desc, q, qd, qdd)
    tool0 = plant.GetBodyByName("tool0").body_frame()
    for k in range(12):
        plant.SetPositions(ctx, q[k])
        plant.SetVelocities(ctx, qd[k])
        forces = MultibodyForces(plant)
        plant.CalcForceElementsContribution(ctx, forces)
        np.testing.assert_allclose(tau[k], plant.CalcInverseDynamics(ctx, qdd[k], forces), rtol=0, atol=1e-10)
        x = tool0.CalcPoseInWorld(ctx).GetAsMatrix4()
        np.testing.assert_allclose(flange_pose(desc, q[k]), x, rtol=0, atol=1e-10)


def test_branching_urdf_needs_a_tip_given_in_yaml(tmp_path):
    (tmp_path / "arm_gripper.urdf").write_text(ros_industrial_urdf(gripper=True))
    with pytest.raises(DescriptionError, match="ambiguous: pass tip_link"):
        load_robot(tmp_path / "arm_gripper.urdf")
    (tmp_path / "arm.yaml").write_text("format: proprio-urdf/v1\nurdf: arm_gripper.urdf\ntip_link: tool0\n")
    desc = load_robot(tmp_path / "arm.yaml")
    (tmp_path / "plain.urdf").write_text(ros_industrial_urdf())
    plain = load_robot(tmp_path / "plain.urdf")
    assert desc.joint_names == plain.joint_names and desc.end_effector == plain.end_effector
    q = np.random.default_rng(1).uniform(-1, 1, (5, 4))
    np.testing.assert_allclose(inverse_dynamics(desc, q, q, q), inverse_dynamics(plain, q, q, q), atol=1e-12)
    (tmp_path / "typo.yaml").write_text("format: proprio-urdf/v1\nurdf: arm_gripper.urdf\ntip_lnk: tool0\n")
    with pytest.raises(DescriptionError, match="tip_lnk: unknown key; did you mean 'tip_link'"):
        load_robot(tmp_path / "typo.yaml")


def test_tx40_urdf_loads():
    shared = Path(os.environ.get("PROPRIO_SHARED", Path(__file__).resolve().parents[2] / "shared"))
    path = shared / "data" / "staubli_tx40" / "tx40_mdh_modified.urdf"
    if not path.exists():
        pytest.skip(f"TX40 data not found at {path}")
    desc = load_robot(path)
    assert desc.n == 6 and desc.end_effector.name == "tool0" and desc.links[0].mass == pytest.approx(10.5)
    np.testing.assert_allclose(desc.lower[[1, 4]], [-2.18, -2.09]) and np.testing.assert_allclose(desc.upper[4], 2.33)


# ---- strict keys -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("path, typo, nearest", [
    ((), "frition", "friction"),
    (("links", 2, "inertia_com"), "ixzz", "ixz"),
    (("links", 1), "com_rpyy", "com_rpy"),
    (("joints", 3, "limits"), "uper_deg", "upper_deg"),
    (("base", "world_to_base_link"), "xzy", "xyz"),
    (("end_effector",), "parnet", "parent"),
])
def test_misspelt_robot_keys_name_the_path_and_nearest_key(path, typo, nearest):
    data = iiwa_dict()
    data.setdefault("end_effector", {"parent": data["links"][-1]["name"]})
    node = data
    for key in path:
        node = node[key]
    node[typo] = 0.0 if typo != "frition" else {"viscous": [0.0] * 7, "coulomb": [0.0] * 7}
    with pytest.raises(DescriptionError, match=re.escape(f"{typo}: unknown key; did you mean '{nearest}'?")) as info:
        robot_from_dict(data, "robot.yaml")
    for key in path:
        assert str(key) in str(info.value)


def test_documentation_keys_are_an_explicit_list(lwr_dir):
    data = yaml.safe_load((lwr_dir / "robot.yaml").read_text())
    assert {"units", "conventions", "alternatives", "nominal_friction_in_source"} <= set(data)
    robot_from_dict(data, "robot.yaml")                       # the documented foreign keys load
    data["unit"] = data.pop("units")
    with pytest.raises(DescriptionError, match="unit: unknown key"):
        robot_from_dict(data, "robot.yaml")


# ---- tolerances with scale ---------------------------------------------------------------------------------------

def _with_link_inertia(k: int, inertia: list[float]) -> dict:
    data = iiwa_dict()
    data["links"][k]["inertia_com"] = dict(zip(("ixx", "iyy", "izz", "ixy", "ixz", "iyz"), inertia))
    data["links"][k]["com_rpy"] = [0.0, 0.0, 0.0]
    return data


def test_inertia_within_numerical_tolerance_is_repaired_with_a_warning():
    # a 0.01 kg·m² link whose smallest principal moment is −1e-8 (a thin rod, rounded), rotated off the axes
    r = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
    i = r @ np.diag([-1e-8, 0.01, 0.01]) @ r.T
    data = _with_link_inertia(3, [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]])
    name = data["links"][3]["name"]
    with pytest.warns(UserWarning, match=rf"links\[3\]\({name}\).*nearest consistent inertia"):
        desc = robot_from_dict(data, "robot.yaml")
    eig = np.linalg.eigvalsh(desc.links[3].inertia_matrix_link())
    assert eig[0] >= 0.0 and eig[0] + eig[1] >= eig[2] - 1e-15
    np.testing.assert_allclose(desc.links[3].inertia_matrix_link(), i, atol=2e-8)   # the nearest one: a tiny change
    # a triangle-inequality deficit of 1e-8 on principal moments of 0.01: repaired to a + b = c
    with pytest.warns(UserWarning, match="triangle|nearest consistent"):
        tri = robot_from_dict(_with_link_inertia(2, [0.004, 0.006, 0.01 + 1e-8, 0, 0, 0]), "robot.yaml")
    a, b, c = np.linalg.eigvalsh(tri.links[2].inertia_matrix_link())
    assert a + b == pytest.approx(c, abs=1e-15)


@pytest.mark.parametrize("inertia, what", [([-1e-3, 0.01, 0.01, 0, 0, 0], "not positive semi-definite"),
                                           ([0.002, 0.003, 0.01, 0, 0, 0], "triangle inequality")])
def test_clearly_non_physical_inertia_is_refused(inertia, what):
    with pytest.raises(DescriptionError, match=what):
        robot_from_dict(_with_link_inertia(1, inertia), "robot.yaml")


# ---- MDH YAML: asymmetric limits and friction ----------------------------------------------------------------------

MDH_ARM = {
    "format": "proprio-mdh/v1", "name": "mdh_arm", "provenance": "test",
    "mdh": {"alpha_deg": [0, -90, 0, -90], "a": [0, 0, 0.4, 0.05], "d": [0.3, 0, 0, 0.35], "flange_d": 0.1},
    "limits": {"lower_deg": [-170, -100, -150, -120], "upper_deg": [170, 140, 60, 120],
               "velocity_deg_s": [120, 120, 150, 180], "effort": [150, 150, 80, 30]},
    "links": [{"name": f"l{k + 1}", "mass": m, "com_xyz": c, "inertia_com": {"ixx": i, "iyy": i, "izz": 0.6 * i}}
              for k, (m, c, i) in enumerate([(6.0, [0, 0, -0.05], 0.05), (5.0, [0.2, 0, 0.02], 0.08),
                                             (3.0, [0.02, -0.15, 0], 0.03), (1.5, [0, 0, 0.05], 0.005)])],
    "friction": {"viscous": [2.0, 1.5, 0.8, 0.3], "coulomb": [3.0, 2.5, 1.2, 0.5]},
}


def test_mdh_yaml_keeps_asymmetric_limits_and_friction():
    desc = robot_from_dict(MDH_ARM, "arm.yaml")
    np.testing.assert_allclose(np.degrees(desc.lower), [-170, -100, -150, -120])
    np.testing.assert_allclose(np.degrees(desc.upper), [170, 140, 60, 120])
    assert desc.friction_viscous == (2.0, 1.5, 0.8, 0.3) and desc.friction_coulomb == (3.0, 2.5, 1.2, 0.5)
    assert desc.provenance == "test" and desc.links[1].mass == 5.0
    for bad, msg in ((dict(MDH_ARM, frition={}), "did you mean 'friction'"),
                     (dict(MDH_ARM, limits=dict(MDH_ARM["limits"], position_deg=[1, 2, 3, 4])), "either symmetric"),
                     (dict(MDH_ARM, limits={"lower_deg": [-1, -1, -1, -1]}), "'lower' and 'upper' go together")):
        with pytest.raises(DescriptionError, match=msg):
            robot_from_dict(bad, "arm.yaml")


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::proprio.description.DescriptionWarning")   # asserted once, below
def test_mdh_arm_with_noisy_published_inertia_runs_twin_identify_diagnose_from_the_cli(tmp_path, monkeypatch, capsys):
    """No Python: an MDH YAML arm (asymmetric limits, friction, one link's inertia with a −1e-8 kg·m² eigenvalue)
    goes through `trajectory rfma`, `simulate`, `identify` (one validation table per file) and `diagnose`."""
    from proprio.cli import main

    monkeypatch.chdir(tmp_path)
    arm = dict(MDH_ARM, limits=dict(MDH_ARM["limits"], acceleration=[5, 5, 6, 8]))
    arm["links"] = [dict(lk) for lk in MDH_ARM["links"]]
    arm["links"][3]["inertia_com"] = {"ixx": -1e-8, "iyy": 0.01, "izz": 0.01}      # a rod along x, rounded
    Path("arm.yaml").write_text(yaml.safe_dump(arm))
    Path("twin.yaml").write_text(yaml.safe_dump({
        "name": "mdh_arm_twin", "robot": "arm.yaml", "time_step": 0.001, "seed": 0,
        "logger": {"rate_hz": 200, "channels": ["q", "tau"]}, "controller": {"kp": 900, "ki": 0, "kd": 60},
        "effects": {}}))
    rfma = yaml.safe_load(resources.files("proprio.configs").joinpath("rfma.yaml").read_text())
    Path("rfma.yaml").write_text(yaml.safe_dump(dict(rfma, robot="arm.yaml", home_deg=[0, 0, 0, 0], scaffolds=3)))
    for seed in (1, 2):
        with pytest.warns(UserWarning, match=r"links\[3\]\(l4\)\.inertia_com.*nearest consistent"):  # the repair
            assert main(["trajectory", "rfma", "--config", "rfma.yaml", "--seed", str(seed),
                         "--out", f"traj{seed}.npz"]) == 0
    for name, traj, seed in (("train", 1, 0), ("val_a", 2, 5), ("val_b", 1, 6)):
        assert main(["simulate", "--twin", "twin.yaml", "--trajectory", f"traj{traj}.npz", "--seconds", "6",
                     "--seed", str(seed), "--quiet", "--out", f"{name}.npz"]) == 0
    capsys.readouterr()
    assert main(["identify", "--robot", "arm.yaml", "--train", "train.npz", "--validate", "val_a.npz", "val_b.npz",
                 "--out", "model.npz"]) == 0
    out = capsys.readouterr().out
    assert out.count("validation: val_a.npz") == 1 and out.count("validation: val_b.npz") == 1
    assert main(["diagnose", "--model", "arm.yaml", "--train", "train.npz", "--holdout", "val_a.npz",
                 "--candidates", "signal_lag", "--out", "diag"]) == 0
    report = json.loads(Path("diag/diagnosis.json").read_text())
    assert report["robot"] == "mdh_arm" and report["model_effects"] == ["viscous_coulomb"]   # its friction is kept
