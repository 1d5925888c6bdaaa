"""The twin's discrete inverse-dynamics controller is the law of Drake's InverseDynamicsController, with the error
integral advanced once per time step (proprio.systems.controller)."""
from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.controllers import InverseDynamicsController

from proprio.description import load_robot
from proprio.plant import DrakeRobot
from proprio.systems.controller import DiscreteInverseDynamicsController

DT = 1e-3


@pytest.fixture(scope="module")
def plant():
    return DrakeRobot(load_robot("iiwa14_identified")).plant


def _fix(system, context, x, x_d, qdd_d, drake: bool) -> None:
    if drake:
        system.get_input_port_estimated_state().FixValue(context, x)
        system.get_input_port_desired_state().FixValue(context, x_d)
        system.get_input_port_desired_acceleration().FixValue(context, qdd_d)
    else:
        system.GetInputPort("estimated_state").FixValue(context, x)
        system.GetInputPort("desired_state").FixValue(context, x_d)
        system.GetInputPort("desired_acceleration").FixValue(context, qdd_d)


@pytest.mark.parametrize("integral", [True, False], ids=["pid", "pd (ki = 0: stateless)"])
def test_equals_drakes_inverse_dynamics_controller_with_the_integral_per_step(plant, integral):
    n = plant.num_velocities()
    rng = np.random.default_rng(3)
    kp, kd = rng.uniform(100, 900, n), rng.uniform(10, 60, n)
    ki = rng.uniform(0, 50, n) if integral else np.zeros(n)
    ours = DiscreteInverseDynamicsController(plant, kp, ki, kd, DT)
    theirs = InverseDynamicsController(plant, kp, ki, kd, True)
    c_ours, c_theirs = ours.CreateDefaultContext(), theirs.CreateDefaultContext()
    for _ in range(5):
        x, x_d = rng.uniform(-1, 1, 2 * n), rng.uniform(-1, 1, 2 * n)
        qdd_d, z = rng.uniform(-2, 2, n), rng.uniform(-0.1, 0.1, n)
        _fix(ours, c_ours, x, x_d, qdd_d, drake=False)
        _fix(theirs, c_theirs, x, x_d, qdd_d, drake=True)
        if integral:
            c_ours.SetDiscreteState(z)                   # the same error integral z [rad·s] in both
        c_theirs.SetContinuousState(z)
        tau = ours.GetOutputPort("generalized_force").Eval(c_ours)
        expected = theirs.get_output_port_generalized_force().Eval(c_theirs)
        assert np.max(np.abs(expected)) > 10.0                                     # N·m: a real command
        np.testing.assert_allclose(tau, expected, rtol=0, atol=1e-9)
        if not integral:
            assert c_ours.num_discrete_state_groups() == 0
            continue
        # one period later the integral has taken explicit Euler's step on the position error
        update = ours.EvalUniquePeriodicDiscreteUpdate(c_ours).get_vector().value()
        np.testing.assert_allclose(update, z + DT * (x_d[:n] - x[:n]), rtol=0, atol=1e-15)


def test_refuses_a_continuous_time_step(plant):
    n = plant.num_velocities()
    with pytest.raises(ValueError, match="time_step must be > 0"):
        DiscreteInverseDynamicsController(plant, np.ones(n), np.zeros(n), np.ones(n), 0.0)
