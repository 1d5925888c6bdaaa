"""Choosing the serial chain of a branching URDF on the command line (``--base``/``--tip``): without them a clear error
that names the candidate tips, with them ``simulate`` and ``identify`` run on the chosen chain."""
from __future__ import annotations

import numpy as np
import pytest

from proprio.cli import main
from proprio.description import DescriptionError, load_robot


def _link(name: str, mass: float, com: str) -> str:
    return (f"<link name='{name}'><inertial><origin xyz='{com}'/><mass value='{mass}'/>"
            "<inertia ixx='0.02' iyy='0.02' izz='0.01' ixy='0' ixz='0' iyz='0'/></inertial></link>")


def _joint(name: str, kind: str, parent: str, child: str, xyz: str, axis: str = "0 1 0") -> str:
    extra = (f"<axis xyz='{axis}'/><limit lower='-2' upper='2' effort='100' velocity='3'/>"
             if kind == "revolute" else "")
    return (f"<joint name='{name}' type='{kind}'><parent link='{parent}'/><child link='{child}'/>"
            f"<origin xyz='{xyz}'/>{extra}</joint>")


TWO_ARMS = ("<?xml version='1.0'?><robot name='two_arms'><link name='world'/>" + _link("base_link", 5.0, "0 0 0.05")
            + _link("torso", 4.0, "0 0 0.2") + _link("arm_a", 2.0, "0.2 0 0") + _link("arm_b", 1.5, "-0.2 0 0")
            + "<link name='tool_a'/><link name='tool_b'/>"
            + _joint("world_joint", "fixed", "world", "base_link", "0 0 0")
            + _joint("waist", "revolute", "base_link", "torso", "0 0 0.1", "0 0 1")
            + _joint("shoulder_a", "revolute", "torso", "arm_a", "0.1 0 0.4")
            + _joint("shoulder_b", "revolute", "torso", "arm_b", "-0.1 0 0.4")
            + _joint("tool_a_joint", "fixed", "arm_a", "tool_a", "0.4 0 0")
            + _joint("tool_b_joint", "fixed", "arm_b", "tool_b", "-0.4 0 0") + "</robot>")


@pytest.fixture
def two_arms(tmp_path):
    path = tmp_path / "two_arms.urdf"
    path.write_text(TWO_ARMS)
    return path


def test_branching_urdf_names_the_candidate_tips(two_arms):
    with pytest.raises(DescriptionError, match=r"branch at link 'torso'.*candidate tips tool_a, tool_b.*--tip LINK"):
        load_robot(two_arms)
    a, b = load_robot(two_arms, tip_link="tool_a"), load_robot(two_arms, base_link="base_link", tip_link="arm_b")
    assert a.joint_names == ["waist", "shoulder_a"] and a.end_effector.name == "tool_a"
    assert b.joint_names == ["waist", "shoulder_b"] and b.links[1].mass == pytest.approx(1.5)
    with pytest.raises(DescriptionError, match="base/tip links select the chain of a URDF file only"):
        load_robot("iiwa14_nominal", tip_link="tool0")


def test_cli_base_and_tip_select_the_chain(two_arms, tmp_path, capsys):
    """``simulate`` (the twin's URDF robot), ``identify`` and ``diagnose`` refuse the ambiguous URDF by naming the
    tips; ``simulate`` and ``identify`` run with ``--tip``, and the identified model holds the chosen arm's joints."""
    from pydrake.trajectories import PiecewisePolynomial

    from proprio.identification.model_io import load_model
    from proprio.systems.trajectories import save_trajectory

    knots = np.random.default_rng(3).uniform(-1.2, 1.2, (8, 2))
    knots[0] = 0.0
    traj = save_trajectory(tmp_path / "motion.npz",
                           PiecewisePolynomial.CubicShapePreserving(np.linspace(0, 4, 8), knots.T, True))
    (tmp_path / "twin.yaml").write_text(f"name: two_arms_twin\nrobot: {two_arms}\n"
                                        "logger: {rate_hz: 1000, channels: [q, tau]}\n")
    rec, model = tmp_path / "rec.npz", tmp_path / "model.npz"
    sim = ["simulate", "--twin", str(tmp_path / "twin.yaml"), "--trajectory", str(traj), "--quiet", "--out", str(rec)]
    ident = ["identify", "--robot", str(two_arms), "--train", str(rec), "--out", str(model)]
    diag = ["diagnose", "--model", str(two_arms), "--train", str(rec), "--out", str(tmp_path / "diag")]
    for args in (sim, ident, diag):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert "candidate tips tool_a, tool_b" in err and "--tip" in err, err
    assert main([*sim, "--tip", "tool_a"]) == 0
    assert main([*ident, "--base", "base_link", "--tip", "tool_a"]) == 0
    fitted = load_model(model)
    assert fitted.description.joint_names == ["waist", "shoulder_a"]
    assert fitted.description.end_effector.name == "tool_a"
