"""Forward kinematics, Jacobians, inverse dynamics, gravity and payloads against Drake, pinocchio and a modified-DH
product (thesis Table 2.2)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pinocchio
import pytest

from proprio.description import load_robot
from proprio.dynamics import gravity_torque, inverse_dynamics
from proprio.kinematics import flange_jacobian, flange_pose, flange_position, link_poses, point_jacobian
from proprio.payload import Payload, attach_payload
from proprio.plant import DrakeRobot, build_plant
from proprio.urdf import to_urdf

IIWA = ["iiwa14_identified", "iiwa14_nominal"]
MDH_ALPHA = np.radians([0, -90, 90, 90, -90, -90, 90])
MDH_D = [0.36, 0.0, 0.42, 0.0, 0.4, 0.0, 0.126]
N_SAMPLES = 25


@pytest.fixture(params=IIWA + ["lwr4"])
def any_robot(request):
    if request.param == "lwr4":
        return load_robot(request.getfixturevalue("lwr_dir"))
    return load_robot(request.param)


def random_states(desc, n=N_SAMPLES, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(desc.lower, desc.upper, (n, desc.n))
    qd = rng.uniform(-1, 1, (n, desc.n)) * desc.velocity_limits
    qdd = rng.uniform(-5, 5, (n, desc.n))
    return q, qd, qdd


def mdh_flange(q: np.ndarray) -> np.ndarray:
    """Flange pose of thesis Table 2.2 (Craig's MDH): Π Rx(α_i) Tx(a_i = 0) Rz(q_i) Tz(d_i)."""
    t = np.eye(4)
    for al, d, qi in zip(MDH_ALPHA, MDH_D, q):
        ca, sa, c, s = math.cos(al), math.sin(al), math.cos(qi), math.sin(qi)
        t = t @ np.array([[c, -s, 0, 0], [s * ca, c * ca, -sa, -sa * d], [s * sa, c * sa, ca, ca * d], [0, 0, 0, 1]])
    return t


# ---- forward kinematics ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", IIWA)
def test_flange_at_zero_configuration(name):
    desc = load_robot(name)
    np.testing.assert_allclose(flange_position(desc, np.zeros(7)), [0.0, 0.0, 1.306], rtol=0, atol=1e-12)
    np.testing.assert_allclose(DrakeRobot(desc).flange_pose(np.zeros(7))[:3, 3], [0.0, 0.0, 1.306], atol=1e-12)


@pytest.mark.parametrize("name", IIWA)
def test_drake_flange_pose_matches_mdh_product(name):
    desc = load_robot(name)
    drake = DrakeRobot(desc)
    # constant rotation between the MDH flange frame and ours, found at q = 0 (pure rotation, here identity)
    c = np.linalg.inv(mdh_flange(np.zeros(7))) @ drake.flange_pose(np.zeros(7))
    np.testing.assert_allclose(c[:3, 3], 0.0, atol=1e-12)
    q_all = np.random.default_rng(1).uniform(desc.lower, desc.upper, (N_SAMPLES, 7))
    for q in q_all:
        pose = drake.flange_pose(q)
        want = mdh_flange(q) @ c
        np.testing.assert_allclose(pose[:3, 3], want[:3, 3], rtol=0, atol=1e-12)   # position
        np.testing.assert_allclose(pose[:3, :3], want[:3, :3], rtol=0, atol=1e-12)  # orientation
    # the batched numpy FK agrees with Drake as well
    np.testing.assert_allclose(flange_pose(desc, q_all), np.stack([drake.flange_pose(q) for q in q_all]),
                               rtol=0, atol=1e-12)


def test_link_poses_match_drake_bodies(any_robot):
    desc = any_robot
    plant = build_plant(desc).plant
    ctx = plant.CreateDefaultContext()
    q = random_states(desc, n=5)[0]
    poses = link_poses(desc, q)
    assert poses.shape == (5, desc.n, 4, 4)
    for k in range(5):
        plant.SetPositions(ctx, q[k])
        for i, lk in enumerate(desc.links):
            x = plant.EvalBodyPoseInWorld(ctx, plant.GetBodyByName(lk.name)).GetAsMatrix4()
            np.testing.assert_allclose(poses[k, i], x, rtol=0, atol=1e-12)


def test_single_sample_shapes():
    desc = load_robot("iiwa14_nominal")
    q = np.full(7, 0.3)
    assert flange_pose(desc, q).shape == (4, 4)
    assert flange_position(desc, q).shape == (3,)
    assert flange_jacobian(desc, q).shape == (6, 7)
    assert inverse_dynamics(desc, q, q, q).shape == (7,)
    with pytest.raises(ValueError, match="7 joint columns"):
        flange_pose(desc, np.zeros(6))


# ---- Jacobian --------------------------------------------------------------------------------------------------------

def test_flange_jacobian_matches_drake(any_robot):
    desc = any_robot
    drake = DrakeRobot(desc)
    q = random_states(desc, seed=2)[0]
    jac = flange_jacobian(desc, q)
    p = np.array([0.05, -0.02, 0.1])
    jac_p = point_jacobian(desc, q, p)
    for k in range(len(q)):
        np.testing.assert_allclose(jac[k], drake.flange_jacobian(q[k]), rtol=0, atol=1e-12)
        np.testing.assert_allclose(jac_p[k], drake.flange_jacobian(q[k], p), rtol=0, atol=1e-12)


def test_jacobian_is_derivative_of_fk():
    desc = load_robot("iiwa14_identified")
    q = random_states(desc, n=3, seed=5)[0]
    h = 1e-6
    jac = flange_jacobian(desc, q)
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = h
        dp = (flange_position(desc, q + dq) - flange_position(desc, q - dq)) / (2 * h)
        np.testing.assert_allclose(jac[:, 3:, i], dp, atol=1e-8)


# ---- inverse dynamics ------------------------------------------------------------------------------------------------

def test_inverse_dynamics_matches_pinocchio_and_drake(any_robot):
    desc = any_robot
    q, qd, qdd = random_states(desc, seed=3)
    tau = inverse_dynamics(desc, q, qd, qdd)
    model = pinocchio.buildModelFromXML(to_urdf(desc, collision=False))
    model.gravity.linear = np.asarray(desc.gravity)
    data = model.createData()
    assert model.nq == desc.n and list(model.names)[1:] == desc.joint_names
    drake = DrakeRobot(desc)
    for k in range(len(q)):
        np.testing.assert_allclose(tau[k], pinocchio.rnea(model, data, q[k], qd[k], qdd[k]), rtol=0, atol=1e-10)
        np.testing.assert_allclose(tau[k], drake.inverse_dynamics(q[k], qd[k], qdd[k]), rtol=0, atol=1e-10)


def test_mass_matrix_from_inverse_dynamics_matches_drake():
    desc = load_robot("iiwa14_identified")
    drake = DrakeRobot(desc)
    q = random_states(desc, n=3, seed=6)[0]
    for qk in q:
        qs = np.repeat(qk[None], 7, axis=0)
        m = (inverse_dynamics(desc, qs, np.zeros((7, 7)), np.eye(7)) - gravity_torque(desc, qs)).T
        np.testing.assert_allclose(m, drake.mass_matrix(qk), rtol=0, atol=1e-12)
        np.testing.assert_allclose(m, m.T, atol=1e-12)
        assert np.linalg.eigvalsh(m).min() > 0


def test_gravity_torque_matches_drake(any_robot):
    desc = any_robot
    drake = DrakeRobot(desc)
    q = random_states(desc, seed=4)[0]
    g = gravity_torque(desc, q)
    for k in range(len(q)):
        drake._set(q[k])
        np.testing.assert_allclose(g[k], -drake.plant.CalcGravityGeneralizedForces(drake.context), rtol=0, atol=1e-10)


def test_iiwa_gravity_vanishes_upright():
    # stretched upright: every CoM is close to the vertical axis, so holding torques are small; joint 2 is not 0
    desc = load_robot("iiwa14_nominal")
    g = gravity_torque(desc, np.zeros(7))
    assert np.abs(g).max() < 1.0
    g_bent = gravity_torque(desc, np.array([0, np.pi / 2, 0, 0, 0, 0, 0]))
    assert abs(g_bent[1]) > 50  # the whole arm horizontal on joint 2


# ---- payload ---------------------------------------------------------------------------------------------------------

PAYLOAD = Payload(mass=1.7, com_flange=(0.02, -0.01, 0.08), inertia=(0.004, 0.005, 0.003, 0.0005, -0.0003, 0.0002))


@pytest.mark.parametrize("name", IIWA)
def test_attach_payload_matches_drake_welded_body(name):
    desc = load_robot(name)
    with_payload = attach_payload(desc, PAYLOAD)
    drake = DrakeRobot(desc, PAYLOAD)
    assert drake.plant.HasBodyNamed("payload")
    q, qd, qdd = random_states(desc, seed=7)
    tau = inverse_dynamics(with_payload, q, qd, qdd)
    for k in range(len(q)):
        np.testing.assert_allclose(tau[k], drake.inverse_dynamics(q[k], qd[k], qdd[k]), rtol=0, atol=1e-10)
    assert not np.allclose(tau, inverse_dynamics(desc, q, qd, qdd))


def test_point_mass_payload_adds_its_weight_through_the_jacobian():
    # a hanging point mass m at p (flange frame) adds −J_v(p)ᵀ·(m g) to the torque the joints must apply
    desc = load_robot("iiwa14_identified")
    payload = Payload(mass=1.0, com_flange=(0.0, 0.03, 0.1))
    q = random_states(desc, n=10, seed=8)[0]
    extra = gravity_torque(attach_payload(desc, payload), q) - gravity_torque(desc, q)
    jv = point_jacobian(desc, q, np.array(payload.com_flange))[:, 3:, :]
    weight = payload.mass * np.asarray(desc.gravity)
    np.testing.assert_allclose(extra, -np.einsum("sij,i->sj", jv, weight), rtol=0, atol=1e-12)


def test_no_payload_is_identity():
    desc = load_robot("iiwa14_nominal")
    assert attach_payload(desc, None) is desc
    assert Payload.from_dict({"mass": 0.0}) is None
    assert Payload.from_dict({"mass": 2.0, "com_flange": [0, 0, 0.1]}) == Payload(2.0, (0.0, 0.0, 0.1))


def test_general_base_pose_gravity_and_inertia_frames():
    """Tilted, offset base; non-vertical gravity; rotated inertia frames; rotated flange — still equal to Drake."""
    desc = load_robot("iiwa14_identified")
    links = list(desc.links)
    links[2] = dataclasses.replace(links[2], com_rpy=(0.4, -0.3, 1.1))
    links[6] = dataclasses.replace(links[6], com_rpy=(-0.2, 0.5, 0.3))
    desc = dataclasses.replace(
        desc, links=tuple(links), world_to_base_xyz=(0.1, -0.2, 0.5), world_to_base_rpy=(0.3, -0.2, 0.7),
        gravity=(1.0, -2.0, -9.0),
        end_effector=dataclasses.replace(desc.end_effector, xyz=(0.01, 0.02, 0.06), rpy=(0.1, 0.2, 0.3)))
    drake = DrakeRobot(desc, PAYLOAD)
    with_payload = attach_payload(desc, PAYLOAD)
    q, qd, qdd = random_states(desc, n=10, seed=9)
    tau = inverse_dynamics(with_payload, q, qd, qdd)
    poses, jac = flange_pose(desc, q), flange_jacobian(desc, q)
    for k in range(len(q)):
        np.testing.assert_allclose(tau[k], drake.inverse_dynamics(q[k], qd[k], qdd[k]), rtol=0, atol=1e-10)
        np.testing.assert_allclose(poses[k], drake.flange_pose(q[k]), rtol=0, atol=1e-12)
        np.testing.assert_allclose(jac[k], drake.flange_jacobian(q[k]), rtol=0, atol=1e-12)
