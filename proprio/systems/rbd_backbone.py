"""The identified rigid-body backbone ``τ_RBD = K_b(q, q̇, q̈) φ_b`` (thesis eq. 4.23) as a Drake ``LeafSystem``.

Input ports ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s²] (size n each); output port ``tau_rbd`` [N·m] (size n):
rigid body + identified friction (+ identified torque offsets), direct feedthrough, no state.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from pydrake.systems.framework import BasicVector, Context, DiagramBuilder, LeafSystem

from proprio.identification.model_io import IdentifiedModel, load_model

__all__ = ["RbdBackbone", "AddRbdBackbone"]


class RbdBackbone(LeafSystem):
    """``tau_rbd = model.torque(q, qd, qdd)`` for an :class:`IdentifiedModel` (or a path to its file)."""

    def __init__(self, model: IdentifiedModel | str | Path):
        super().__init__()
        self.model = model if isinstance(model, IdentifiedModel) else load_model(model)
        if self.model.sensor is not None:
            raise ValueError("RbdBackbone: the model has torque-sensor terms, whose reversal state this stateless "
                             "System cannot carry; load the model file with proprio.diagrams.torque_model."
                             "load_rigid_torque_model(path) and use TorqueModelSystem(that model, period_s=<the "
                             "step, s>) on the rigid-body torque (its inputs tau_rigid, q, qd, qdd)")
        n = self.model.n
        self._q = self.DeclareVectorInputPort("q", n)
        self._qd = self.DeclareVectorInputPort("qd", n)
        self._qdd = self.DeclareVectorInputPort("qdd", n)
        self.DeclareVectorOutputPort("tau_rbd", n, self._calc_tau)

    def _calc_tau(self, context: Context, output: BasicVector) -> None:
        q = self._q.Eval(context)
        qd = self._qd.Eval(context)
        qdd = self._qdd.Eval(context)
        output.SetFromVector(np.asarray(self.model.torque(q, qd, qdd)))


def AddRbdBackbone(builder: DiagramBuilder, model: IdentifiedModel | str | Path,
                   name: str = "rbd_backbone") -> RbdBackbone:
    """Add an :class:`RbdBackbone` to ``builder`` and return it (ports ``q``, ``qd``, ``qdd`` → ``tau_rbd``)."""
    system = builder.AddSystem(RbdBackbone(model))
    system.set_name(name)
    return system
