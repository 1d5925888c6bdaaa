"""The data's position-noise floor against the model's encoder noise: a data-path finding of the gap diagnosis.

Extra encoder noise cannot be found by held-out prediction: after the conditioning's low-pass its torque effect is
band-limited random noise that no candidate predicts on held-out blocks. It is found by comparing noise *levels*:

* **measured**: the white floor of ``Δ²q`` that the conditioning estimates per joint (``ConditionedSignals.sigma_q``,
  from the upper half of the band, where arm motion has no power) with its χ² degrees of freedom ``D_k``
  (:func:`proprio.cutoff.noise_floor_dof`), pooled over the recordings: ``σ̂² = Σ D_k σ̂_k² / Σ D_k``,
  ``D = Σ D_k``, and ``D σ̂² / σ² ~ χ²_D`` gives its 95 % confidence interval;
* **modelled**: what the model's ``encoder_noise`` effect predicts for the same floor, ``σ² = std² + res²/12``
  (white noise, then rounding to the resolution ``res``); a model without that effect states no encoder at all.

The data's floor is *above the model's* on a joint when ``σ̂² > σ_m² · 1.2 · χ²_{D, 1−α/n} / D`` (one-sided, α = 1 %,
Bonferroni over the ``n`` joints, plus 20 % of slack: the rule of the torque-noise finding in
:mod:`proprio.diagnosis.selection.forward`). Then ``encoder_noise`` is a data-path finding: reported in the diagnosis'
"data and processing" section, never as the physical cause of the gap. A model without an encoder-noise effect
gives no level to compare with: the measured floor is reported as information only (every real encoder has some
noise; claiming it as a finding against an unstated sensor would fire on every log).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from scipy import stats

from proprio.conditioning import ConditionedSignals
from proprio.diagnosis.data import SimModel

__all__ = ["EncoderFloor", "encoder_floor", "ENCODER_FLOOR_ALPHA", "ENCODER_FLOOR_SLACK"]

ENCODER_FLOOR_ALPHA = 0.01      # one-sided level of the "floor above the model's" test (Bonferroni over joints)
ENCODER_FLOOR_SLACK = 1.2       # variance slack, as for the torque-noise finding


@dataclass
class EncoderFloor:
    """The data's white position-noise floor against the model's encoder noise (module docstring).

    ``measured [n]`` rad: pooled σ̂_q; ``lower, upper [n]`` rad: its 95 % confidence interval; ``dof``: the χ²
    degrees of freedom of σ̂² (all recordings); ``modelled [n]`` rad: ``√(std² + res²/12)`` of the model's
    ``encoder_noise`` effect, ``None`` when the model has none; ``bound [n]`` rad: the level σ̂ must exceed to be
    above the model's (``None`` without a modelled level); ``excess [n]``: joints whose floor is above it."""
    measured: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    dof: float
    modelled: np.ndarray | None
    bound: np.ndarray | None
    excess: np.ndarray
    name: str = "encoder_noise"

    @property
    def reported(self) -> bool:
        """A data-path finding: the data's floor is above the model's encoder noise on at least one joint."""
        return bool(self.excess.any())

    def text(self, joint_names: Sequence[str]) -> str:
        """One paragraph for the report's data-and-processing section, σ in µrad."""
        u = 1e6
        meas = ", ".join(f"{u * m:.3g} [{u * lo:.3g}, {u * hi:.3g}]" for m, lo, hi in
                         zip(self.measured, self.lower, self.upper))
        head = (f"Position-noise floor of the data (white floor of Δ²q, pooled over the recordings, {self.dof:.0f} "
                f"degrees of freedom), σ̂_q per joint with 95 % CI: {meas} µrad.")
        if self.modelled is None:
            return (head + " The model has no encoder noise (an ideal position sensor), so there is no level to "
                    "compare with: information only. Give the model an encoder_noise effect (std, resolution) to "
                    "test the data's floor against it.")
        model = ", ".join(f"{u * m:.3g}" for m in self.modelled)
        if not self.reported:
            return (head + f" The model's encoder noise predicts {model} µrad (√(std² + res²/12)); the data's "
                    "floor is within it on every joint.")
        joints = ", ".join(f"{joint_names[j]} ({self.measured[j] / self.modelled[j]:.2g}×)" if self.modelled[j] > 0
                           else f"{joint_names[j]} (the model states an ideal sensor)"
                           for j in np.flatnonzero(self.excess))
        return (head + f" The model's encoder noise predicts {model} µrad (√(std² + res²/12)). Data path: "
                f"position-encoder noise above the model's on {joints} — the measured floor exceeds the model's "
                f"beyond its {100 * (1 - ENCODER_FLOOR_ALPHA):.0f} % bound (with 20 % slack). It enters the "
                "derivatives the diagnosis differentiates from q, not the robot's dynamics: not a cause of the gap.")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (σ in rad)."""
        opt = lambda x: None if x is None else [float(v) for v in x]  # noqa: E731
        return {"name": self.name, "reported": self.reported, "measured_sigma": opt(self.measured),
                "ci95_lower": opt(self.lower), "ci95_upper": opt(self.upper), "dof": float(self.dof),
                "modelled_sigma": opt(self.modelled), "bound_sigma": opt(self.bound),
                "excess": [bool(x) for x in self.excess]}


def encoder_floor(model: SimModel, conditioned: Sequence[ConditionedSignals], alpha: float = ENCODER_FLOOR_ALPHA,
                  slack: float = ENCODER_FLOOR_SLACK) -> EncoderFloor:
    """Compare the recordings' pooled position-noise floor with the model's encoder noise (module docstring).

    ``conditioned``: every recording of the diagnosis, whole (not cross-validation pieces, which share one floor)."""
    n = model.robot.n
    dof_k = np.array([cs.sigma_q_dof for cs in conditioned], dtype=float)
    dof = float(dof_k.sum())
    if dof <= 0:
        var = np.zeros(n)
        lower, upper = np.zeros(n), np.full(n, np.inf)
    else:
        var = (dof_k[:, None] * np.array([cs.sigma_q ** 2 for cs in conditioned])).sum(axis=0) / dof
        lower = np.sqrt(var * dof / stats.chi2.ppf(0.975, dof))
        upper = np.sqrt(var * dof / stats.chi2.ppf(0.025, dof))
    enc = [e for e in model.effects if e.name == "encoder_noise"]
    if not enc or dof <= 0:
        modelled = None if not enc else np.sqrt(_modelled_variance(enc[0]))
        return EncoderFloor(np.sqrt(var), lower, upper, dof, modelled, None, np.zeros(n, dtype=bool))
    m_var = _modelled_variance(enc[0])
    bound = np.sqrt(m_var * slack * stats.chi2.ppf(1.0 - alpha / n, dof) / dof)
    return EncoderFloor(np.sqrt(var), lower, upper, dof, np.sqrt(m_var), bound, np.sqrt(var) > bound)


def _modelled_variance(effect: Any) -> np.ndarray:
    """``std² + res²/12`` [rad²] per joint of an :class:`~proprio.effects.EncoderNoise`: white noise, then uniform
    rounding error of the quantisation (valid while ``std`` is not far below ``res``)."""
    return np.asarray(effect.std, dtype=float) ** 2 + np.asarray(effect.resolution, dtype=float) ** 2 / 12.0
