"""The inertial-parameter regressor against proprio.dynamics, Drake's CalcInverseDynamics and pinocchio."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from proprio import friction_law
from proprio.description import Link, load_robot
from proprio.dynamics import inverse_dynamics
from proprio.identification.regressor import (
    PARAMS_PER_JOINT, parameter_names, parameters_to_links, predict, regressor, regressor_buffer,
    standard_parameters)


def random_links(desc, rng) -> list[Link]:
    """Physically valid random inertials: positive mass, CoM within 0.2 m, principal moments obeying the
    triangle inequality, random principal axes."""
    links = []
    for lk in desc.links:
        m = rng.uniform(0.5, 5.0)
        a, b = rng.uniform(0.01, 0.1, size=2)
        c = rng.uniform(abs(a - b) + 1e-3, a + b)
        r, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        i_c = r @ np.diag([a, b, c]) @ r.T
        inertia = tuple(float(i_c[a_, b_]) for a_, b_ in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)))
        links.append(dataclasses.replace(lk, mass=float(m), com_xyz=tuple(float(x) for x in rng.uniform(-0.2, 0.2, 3)),
                                         com_rpy=(0.0, 0.0, 0.0), inertia_com=inertia))
    return links


def random_states(desc, rng, n_samples):
    q = rng.uniform(desc.lower, desc.upper, size=(n_samples, desc.n))
    return q, rng.normal(size=q.shape), rng.normal(size=q.shape) * 3


def test_matches_rnea_with_friction(iiwa):
    rng = np.random.default_rng(0)
    desc = iiwa.with_inertials(random_links(iiwa, rng))
    q, qd, qdd = random_states(desc, rng, 300)
    y = regressor(desc, q, qd, qdd)
    assert y.shape == (300, 7, 84)
    phi = standard_parameters(desc)
    ref = inverse_dynamics(desc, q, qd, qdd) + friction_law.viscous_coulomb(qd, np.array(desc.friction_viscous),
                                                                            np.array(desc.friction_coulomb))
    np.testing.assert_allclose(np.einsum("snp,p->sn", y, phi), ref, atol=1e-10, rtol=0)
    np.testing.assert_allclose(predict(y.base, phi), ref, atol=1e-10, rtol=0)


def test_matches_rnea_lwr_and_smooth_coulomb(lwr_dir):
    rng = np.random.default_rng(1)
    lwr = load_robot(lwr_dir)
    desc = lwr.with_inertials(random_links(lwr, rng))
    q, qd, qdd = random_states(desc, rng, 200)
    phi = standard_parameters(desc)
    phi[10::12], phi[11::12] = 0.3, 0.2
    y = regressor(desc, q, qd, qdd, coulomb_velocity_scale=0.02)
    ref = inverse_dynamics(desc, q, qd, qdd) + 0.3 * qd + 0.2 * np.tanh(qd / 0.02)
    np.testing.assert_allclose(np.einsum("snp,p->sn", y, phi), ref, atol=1e-10, rtol=0)


@pytest.mark.parametrize("name", ["iiwa14_identified", "iiwa14_nominal"])
def test_matches_drake_inverse_dynamics(name):
    from proprio.plant import DrakeRobot

    rng = np.random.default_rng(2)
    base = load_robot(name)
    desc = base.with_inertials(random_links(base, rng))
    drake = DrakeRobot(desc)
    q, qd, qdd = random_states(desc, rng, 20)
    tau = np.einsum("snp,p->sn", regressor(desc, q, qd, qdd), standard_parameters(desc.without_friction()))
    ref = np.array([drake.inverse_dynamics(*x) for x in zip(q, qd, qdd)])
    np.testing.assert_allclose(tau, ref, atol=1e-10, rtol=0)


def test_matches_pinocchio_regressor(iiwa):
    """pinocchio's columns per joint: [m, mc, Ixx, Ixy, Iyy, Ixz, Iyz, Izz] about the joint (= link) frame."""
    pin = pytest.importorskip("pinocchio")
    from proprio.urdf import to_urdf

    rng = np.random.default_rng(3)
    model = pin.buildModelFromXML(to_urdf(iiwa, collision=False))
    data = model.createData()
    ours_to_pin = [0, 1, 2, 3, 4, 5, 7, 6, 8, 9]       # pin column k holds our column ours_to_pin[k]
    q, qd, qdd = random_states(iiwa, rng, 30)
    y = regressor(iiwa, q, qd, qdd)
    for k in range(q.shape[0]):
        y_pin = pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k])
        for j in range(iiwa.n):
            np.testing.assert_allclose(y[k][:, 12 * j:12 * j + 10][:, ours_to_pin], y_pin[:, 10 * j:10 * j + 10],
                                       atol=1e-10, rtol=0)


def test_upper_block_triangular_and_friction_columns(iiwa):
    rng = np.random.default_rng(4)
    q, qd, qdd = random_states(iiwa, rng, 50)
    buf = regressor_buffer(iiwa, q, qd, qdd)
    for i in range(iiwa.n):
        assert not buf[i, :12 * i].any()                 # joint i never sees links before it
        np.testing.assert_array_equal(buf[i, 12 * i + 10], qd[:, i])
        np.testing.assert_array_equal(buf[i, 12 * i + 11], friction_law.smooth_sign(qd[:, i]))
    exact = regressor_buffer(iiwa, q, qd, qdd, coulomb_velocity_scale=0.0)        # the law's limit: sign(q̇)
    for i in range(iiwa.n):
        np.testing.assert_array_equal(exact[i, 12 * i + 11], np.sign(qd[:, i]))


def test_parameters_round_trip(iiwa):
    rng = np.random.default_rng(5)
    links = random_links(iiwa, rng)
    desc = iiwa.with_inertials(links)
    back = parameters_to_links(standard_parameters(desc), desc)
    for a, b in zip(links, back):
        assert a.mass == pytest.approx(b.mass, abs=1e-14)
        np.testing.assert_allclose(a.com_xyz, b.com_xyz, atol=1e-14)
        np.testing.assert_allclose(a.inertia_matrix_link(), b.inertia_matrix_link(), atol=1e-13)
    assert parameter_names(7)[PARAMS_PER_JOINT * 2 + 9] == "Izz3"


def test_bad_input_raises(iiwa):
    with pytest.raises(ValueError, match=r"q must be \[N,7\]"):
        regressor(iiwa, np.zeros((3, 6)), np.zeros((3, 6)), np.zeros((3, 6)))
    phi = standard_parameters(iiwa)
    phi[0] = -1.0
    with pytest.raises(ValueError, match="m1"):
        parameters_to_links(phi, iiwa)
