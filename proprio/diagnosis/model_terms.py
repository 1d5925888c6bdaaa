"""A log that lacks a term of the model: some drives compensate gravity internally, so their logged torque holds little
or no gravity; others log only what they add to a feed-forward of the whole rigid-body torque. The residual
``e = τ_meas − τ_sim`` then is the *negative* of that model term, and a diagnosis that does not say so fits offsets
with huge intervals or a rigid-body "error" of −100 %.

**Test** (:func:`missing_model_term`). For each of two model terms ``x`` — the model's gravity torque ``τ_g(q) =
ID(q, 0, 0)`` and the whole modelled torque ``τ_sim`` — fit per joint ``e_j ≈ a_j x_j + c_j`` on the training data
and score it on the held-out data against the constant alone: ``G = 1 − Σ_j SSE(e_j − a_j x_j − c_j) / Σ_j
SSE(e_j − c_j)`` over the joints that carry the term (its held-out RMS at least :data:`LOAD_SHARE` of the largest
joint's and of that joint's residual RMS). The log lacks the term when ``G ≥`` :data:`MIN_EXPLAINED` and every such
joint's ``a_j`` lies within :data:`COEFFICIENT_BAND` of −1. Gravity is named when it explains nearly as much as the
whole torque (within 0.05 of ``G``: the narrower statement); the whole rigid-body torque otherwise.
A finding of the report (:attr:`proprio.diagnosis.attribution.Attribution.missing_term`), never a library effect.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from proprio.diagnosis.data import GapData, SimModel
from proprio.dynamics import inverse_dynamics

__all__ = ["MissingTerm", "missing_model_term", "MIN_EXPLAINED", "COEFFICIENT_BAND", "LOAD_SHARE"]

MIN_EXPLAINED = 0.5            # held-out share of the residual (beyond a constant) the term must explain
COEFFICIENT_BAND = 0.35        # |a_j + 1| at most: "the negative of the term", a drive's scale error allowed
LOAD_SHARE = 0.3               # a joint carries the term: RMS ≥ this × the largest joint's and × its residual RMS


@dataclass
class MissingTerm:
    """The logged τ seems to lack the model term ``term`` (``"gravity"`` | ``"rigid_body_torque"``): on ``joints``
    (0-based) the residual is ``coefficients`` × the term (≈ −1), explaining ``explained`` of the held-out residual
    beyond a constant there."""
    term: str
    joints: list[int]
    coefficients: list[float]
    explained: float

    def text(self, joint_names: Sequence[str]) -> str:
        """The finding as one sentence (the report places it first: every effect below is read on such a log)."""
        what = "gravity" if self.term == "gravity" else "the model's whole rigid-body torque"
        return (f"The logged τ seems to exclude {what}: the drive may compensate it. On "
                f"{', '.join(joint_names[j] for j in self.joints)} the residual follows "
                f"{', '.join(f'{a:+.2f}' for a in self.coefficients)} × the modelled "
                f"{'gravity torque' if self.term == 'gravity' else 'torque'}, {100 * self.explained:.0f} % of the "
                "held-out residual beyond a constant — effects fitted on such a log (offsets above all) stand in for "
                f"the missing term; compare with a model without {what}.")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``diagnosis.json`` ``missing_term``)."""
        return {"term": self.term, "joints": self.joints, "coefficients": self.coefficients,
                "explained": self.explained}


def _gravity(model: SimModel, data: GapData) -> np.ndarray:
    return data.stack([inverse_dynamics(model.robot, s.q, np.zeros_like(s.q), np.zeros_like(s.q))
                       for s in data.signals])


def _test(x_tr: np.ndarray, e_tr: np.ndarray, x_h: np.ndarray, e_h: np.ndarray
          ) -> tuple[float, list[int], np.ndarray]:
    """``(G, joints carrying the term, a per joint)`` of the module docstring's fit."""
    xc, ec = x_tr - x_tr.mean(axis=0), e_tr - e_tr.mean(axis=0)
    a = (xc * ec).sum(axis=0) / np.maximum((xc ** 2).sum(axis=0), 1e-300)
    c = e_tr.mean(axis=0) - a * x_tr.mean(axis=0)
    rx, re = np.sqrt((x_h ** 2).mean(axis=0)), np.sqrt((e_h ** 2).mean(axis=0))
    joints = np.flatnonzero((rx >= LOAD_SHARE * rx.max()) & (rx >= LOAD_SHARE * re) & (rx > 0))
    if not joints.size:
        return 0.0, [], a
    sse = ((e_h - a * x_h - c) ** 2).sum(axis=0)[joints].sum()
    sse0 = ((e_h - e_tr.mean(axis=0)) ** 2).sum(axis=0)[joints].sum()
    return float(1.0 - sse / max(sse0, 1e-300)), [int(j) for j in joints], a


def missing_model_term(model: SimModel, train: GapData, hold: GapData) -> MissingTerm | None:
    """The model term the logged τ seems to lack (module docstring), or ``None``."""
    e_tr, e_h = train.residual, hold.residual
    found = []
    for term, x_tr, x_h in (("gravity", _gravity(model, train), _gravity(model, hold)),
                            ("rigid_body_torque", train.stack(train.tau_sim), hold.stack(hold.tau_sim))):
        g, joints, a = _test(x_tr, e_tr, x_h, e_h)
        ok = g >= MIN_EXPLAINED and joints and np.all(np.abs(a[joints] + 1.0) <= COEFFICIENT_BAND)
        found.append((term, g, joints, a, bool(ok)))
    (g_name, g_g, g_j, g_a, g_ok), (r_name, r_g, r_j, r_a, r_ok) = found
    if g_ok and (not r_ok or g_g >= r_g - 0.05):
        return MissingTerm(g_name, g_j, [float(g_a[j]) for j in g_j], g_g)
    if r_ok:
        return MissingTerm(r_name, r_j, [float(r_a[j]) for j in r_j], r_g)
    return None
