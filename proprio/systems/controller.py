"""The twin's joint controller: inverse dynamics on a PID acceleration command, as a discrete-time Drake Diagram.

    q̈_c = q̈_d + K_p (q_d − q) + K_d (q̇_d − q̇) + K_i z,      z⁺ = z + Δt (q_d − q)
    τ   = M(q) q̈_c + C(q, q̇) q̇ − τ_g(q)                       (Drake's ``InverseDynamics`` on the control plant)

It is the law of Drake's ``InverseDynamicsController`` with the error integral ``z`` [rad·s] advanced once per
period ``Δt`` (explicit Euler, as a digital controller does) instead of as continuous state. The difference matters
for the speed of the twin: with no continuous state in its Diagram the Simulator takes pure discrete steps, without an
integrator's derivative evaluation of the whole Diagram between the plant's steps (≈ 25 % of a twin step; with
``K_i = 0``, every shipped twin, the two controllers give the same torques to rounding — test). Everything is C++: a
discrete ``LinearSystem`` holds the PID (state ``z``, input ``[q_d; q̇_d; q; q̇]``; with ``K_i = 0`` a stateless
``MatrixGain``, the PD law), an ``Adder`` adds ``q̈_d`` and ``InverseDynamics`` turns the command into joint torques.
"""
from __future__ import annotations

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.controllers import InverseDynamics
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Adder, LinearSystem, MatrixGain, Multiplexer

__all__ = ["DiscreteInverseDynamicsController", "AddDiscreteInverseDynamicsController"]


class DiscreteInverseDynamicsController(Diagram):
    """Inverse dynamics on a discrete PID command (module docstring).

    Args:
        plant: the controller's model of the arm (a continuous ``MultibodyPlant``; kept alive by this Diagram).
        kp: ``K_p`` [1/s²] per joint.
        ki: ``K_i`` [1/s³] per joint.
        kd: ``K_d`` [1/s] per joint.
        time_step: ``Δt`` [s], the period of the integral's update (the twin's time step).

    Input ports: ``estimated_state`` [2n] = [q; q̇] (rad, rad/s), ``desired_state`` [2n], ``desired_acceleration``
    [n] rad/s². Output port: ``generalized_force`` [n] N·m.
    """

    def __init__(self, plant: MultibodyPlant, kp: np.ndarray, ki: np.ndarray, kd: np.ndarray, time_step: float):
        Diagram.__init__(self)
        n = plant.num_velocities()
        kp, ki, kd = (np.asarray(k, dtype=float).reshape(n) for k in (kp, ki, kd))
        if time_step <= 0:
            raise ValueError(f"DiscreteInverseDynamicsController: time_step must be > 0, got {time_step}")
        self.plant = plant
        eye, zero = np.eye(n), np.zeros((n, n))
        gains = np.hstack([np.diag(kp), np.diag(kd)])                     # on the state error [q_d − q; q̇_d − q̇]
        if np.any(ki != 0):
            pid = LinearSystem(A=eye, B=time_step * np.hstack([eye, zero, -eye, zero]), C=np.diag(ki),
                               D=np.hstack([gains, -gains]), time_period=time_step)
        else:                                                      # K_i = 0: a PD law, no state to update
            pid = MatrixGain(np.hstack([gains, -gains]))
        b = DiagramBuilder()
        states = b.AddNamedSystem("states", Multiplexer([2 * n, 2 * n]))           # [x_d; x]
        pid = b.AddNamedSystem("pid", pid)
        command = b.AddNamedSystem("acceleration_command", Adder(2, n))
        inverse = b.AddNamedSystem("inverse_dynamics", InverseDynamics(
            plant, InverseDynamics.InverseDynamicsMode.kInverseDynamics))
        b.Connect(states.get_output_port(), pid.get_input_port())
        b.Connect(pid.get_output_port(), command.get_input_port(0))
        b.Connect(command.get_output_port(), inverse.get_input_port_desired_acceleration())
        b.ExportInput(inverse.get_input_port_estimated_state(), "estimated_state")
        b.ConnectInput("estimated_state", states.get_input_port(1))
        b.ExportInput(states.get_input_port(0), "desired_state")
        b.ExportInput(command.get_input_port(1), "desired_acceleration")
        b.ExportOutput(inverse.get_output_port_generalized_force(), "generalized_force")
        b.BuildInto(self)


def AddDiscreteInverseDynamicsController(builder: DiagramBuilder, plant: MultibodyPlant, kp: np.ndarray,
                                         ki: np.ndarray, kd: np.ndarray, time_step: float,
                                         name: str = "controller") -> DiscreteInverseDynamicsController:
    """Add a :class:`DiscreteInverseDynamicsController` named ``name`` to ``builder`` and return it."""
    ctrl = builder.AddSystem(DiscreteInverseDynamicsController(plant, kp, ki, kd, time_step))
    ctrl.set_name(name)
    return ctrl
