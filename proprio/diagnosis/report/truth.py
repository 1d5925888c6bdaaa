"""Scoring a diagnosis of twin data against the twin's truth: which of the effect families the twin simulated were
named, and how close the fitted parameters are to the true ones (DESIGN.md "Gap diagnosis", step 5, on a mixture).

The truth is what the twin wrote into its Recordings: ``meta["effects"]`` (every joint effect with its parameters),
``meta["robot_description"]`` (the simulated robot; older Recordings: the built-in robot named ``meta["robot"]``),
``meta["payload"]``, and the exact motion ``truth__q_true/qd/qdd``. The diagnosis never
reads any of it; this module only compares afterwards (the demo's "diagnosis against the truth" table, and the
report's section when the held-out data come from the twin).

Families (a family is named when any of its diagnosis names is a physical step, tied alternative or noise finding):

================== =========================================== ==================================================
family              diagnosis names                              compared
================== =========================================== ==================================================
rigid body          ``rigid_body``                               torque: true Δτ_rbd + g·τ vs the fitted correction
friction            ``viscous_coulomb``, ``stribeck``            viscous, Coulomb level
hysteresis          ``hysteresis``                               saturation, saturation travel
lost motion         ``lost_motion``                              amplitude, window
ripple              ``ripple``                                   amplitude √(sin² + cos²)
sensor offset/gain  ``sensor_offset``, ``sensor_gain``           offset, gain
torque noise        ``torque_noise`` (noise finding)             σ
payload             ``payload``                                  mass
================== =========================================== ==================================================

Position-encoder noise is a data-path item (reported apart by the diagnosis) and the motor-side drive is hidden
behind the torque sensor, so neither is a family here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from proprio.description import DescriptionError, RobotDescription, load_robot, robot_from_dict
from proprio.diagnosis.data import SimModel
from proprio.diagnosis.attribution import Attribution
from proprio.dynamics import inverse_dynamics
from proprio.identification.regressor import PARAMS_PER_JOINT, parameter_names, regressor, standard_parameters
from proprio.payload import Payload
from proprio.recording import Recording

__all__ = ["FAMILIES", "ParameterRow", "TruthComparison", "compare_to_truth", "truth_summary"]

FAMILIES: dict[str, tuple[tuple[str, ...], str | None]] = {
    "rigid body": (("rigid_body",), None),
    "friction": (("viscous_coulomb", "stribeck"), "viscous_coulomb"),
    "hysteresis": (("hysteresis",), "hysteresis"),
    "lost motion": (("lost_motion",), "lost_motion"),
    "ripple": (("ripple",), "ripple"),
    "sensor offset/gain": (("sensor_offset", "sensor_gain", "sensor_offset_gain"), "sensor_offset_gain"),
    "torque noise": (("torque_noise",), "torque_noise"),
    "payload": (("payload",), None),
}

# (family, diagnosis step, twin effect, parameter, shown as, unit, scale to the unit)
_PARAMETERS = [
    ("friction", "viscous_coulomb", "viscous_coulomb", "viscous", "viscous F_v", "N·m·s/rad", 1.0),
    ("friction", "viscous_coulomb", "viscous_coulomb", "coulomb", "Coulomb F_c", "N·m", 1.0),
    ("hysteresis", "hysteresis", "hysteresis", "saturation", "saturation", "N·m", 1.0),
    ("hysteresis", "hysteresis", "hysteresis", "saturation_travel", "saturation travel", "°", math.degrees(1.0)),
    ("lost motion", "lost_motion", "lost_motion", "amplitude", "amplitude", "N·m", 1.0),
    ("lost motion", "lost_motion", "lost_motion", "window", "window", "°", math.degrees(1.0)),
    ("sensor offset/gain", "sensor_offset", "sensor_offset_gain", "offset", "offset", "N·m", 1.0),
    ("sensor offset/gain", "sensor_gain", "sensor_offset_gain", "gain", "gain error", "%", 100.0),
]


@dataclass
class ParameterRow:
    """One parameter per joint: the twin's value, the fitted one and its 95 % CI half-width (NaN: not fitted)."""
    family: str
    parameter: str
    unit: str
    truth: np.ndarray
    fitted: np.ndarray
    ci: np.ndarray


@dataclass
class TruthComparison:
    """Result of :func:`compare_to_truth`: families present in the data, families named, parameter rows, and for
    the rigid body the per-joint RMS [N·m] of the true torque difference and of what the fitted correction leaves."""
    present: list[str]
    named: list[str]
    rows: list[ParameterRow]
    rigid_true_rms: np.ndarray | None = None
    rigid_left_rms: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def named_present(self) -> list[str]:
        return [f for f in self.present if f in self.named]

    def markdown(self, joint_names: Sequence[str]) -> str:
        """The comparison as Markdown: one line of named families, then one table row per parameter and joint."""
        n = len(joint_names)
        missed = [f for f in self.present if f not in self.named]
        extra = [f for f in self.named if f not in self.present]
        out = [f"Named {len(self.named_present)} of the {len(self.present)} effect families present in the twin "
               f"data ({', '.join(self.named_present) or 'none'})"
               + (f"; not named: {', '.join(missed)}" if missed else "")
               + (f"; named but absent: {', '.join(extra)}" if extra else "") + ".", ""]
        head = "| family | parameter | " + " | ".join(f"J{j + 1}" for j in range(n)) + " |"
        out += [head, "|" + "---|" * (n + 2)]
        for r in self.rows:
            cells = [f"{t:.3g} / " + ("—" if not np.isfinite(f) else f"{f:.3g}" + (f" ± {c:.2g}" if np.isfinite(c)
                                                                                   else ""))
                     for t, f, c in zip(r.truth, r.fitted, r.ci)]
            out.append(f"| {r.family} | {r.parameter} [{r.unit}] (true / fitted) | " + " | ".join(cells) + " |")
        if self.rigid_true_rms is not None:
            share = 1.0 - (self.rigid_left_rms ** 2) / np.maximum(self.rigid_true_rms ** 2, 1e-300)
            out.append("| rigid body | Δτ_rbd + gain error·τ RMS [N·m] (true / left after the fitted correction) | "
                       + " | ".join(f"{a:.3g} / {b:.3g} ({100 * s:.0f} % explained)"
                                    for a, b, s in zip(self.rigid_true_rms, self.rigid_left_rms, share)) + " |")
        out += [""] + [f"- {x}" for x in self.notes]
        return "\n".join(out)


def _final_params(att: Attribution) -> dict[str, tuple[np.ndarray, np.ndarray, list[str]]]:
    """The fitted parameters of every selected candidate after the last step's joint refit."""
    return att.steps[-1].params if att.steps else {}


def _true_effects(recs: Sequence[Recording]) -> dict[str, dict[str, np.ndarray]]:
    eff = recs[0].meta.get("effects") or {}
    return {k: {p: np.asarray(v, dtype=float) for p, v in block.items()} for k, block in eff.items()}


def _present(effects: dict[str, dict[str, np.ndarray]], true_robot: RobotDescription, model: SimModel,
             payload: Payload | None) -> list[str]:
    """Families the data have and the model lacks (an effect at zero amplitude is absent)."""
    amplitude = {"viscous_coulomb": ("viscous", "coulomb"), "hysteresis": ("saturation",),
                 "lost_motion": ("amplitude",), "ripple": ("sin_amplitude", "cos_amplitude"),
                 "sensor_offset_gain": ("offset", "gain"), "torque_noise": ("std",)}
    out = []
    if not np.allclose(_inertials(true_robot), _inertials(model.robot)):
        out.append("rigid body")
    for family, (_, effect) in FAMILIES.items():
        if effect is None or effect in model.effect_names or effect not in effects:
            continue
        if any(np.any(effects[effect].get(k, 0.0) != 0.0) for k in amplitude[effect]):
            out.append(family)
    if payload is not None and payload.mass > 0:
        out.append("payload")
    return out


def _inertials(robot: RobotDescription) -> np.ndarray:
    phi = standard_parameters(robot)[:PARAMS_PER_JOINT * robot.n].reshape(robot.n, PARAMS_PER_JOINT)
    return phi[:, :10].reshape(-1)


def _rigid_correction(names: list[str], theta: np.ndarray, robot: RobotDescription, q: np.ndarray,
                      qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """Torque ``[N,n]`` of the fitted rigid-body correction (``rigid_body`` parameters ``δ<name>``)."""
    full = parameter_names(robot.n)
    delta = np.zeros(len(full))
    for nm, v in zip(names, theta):
        delta[full.index(nm[1:])] = v
    return regressor(robot, q, qd, qdd)[..., :len(full)] @ delta             # link columns (not a drive's)


def compare_to_truth(att: Attribution, model: SimModel, holdout: Sequence[Recording]) -> TruthComparison | None:
    """Compare ``att`` (a diagnosis of ``model`` on data whose held-out recordings ``holdout`` came from the twin)
    with the twin's truth; ``None`` when the recordings carry no twin truth (``meta["effects"]``,
    ``truth__q_true``) or the twin's robot cannot be rebuilt."""
    if not holdout or any("effects" not in r.meta or "q_true" not in r.truth for r in holdout):
        return None
    effects = _true_effects(holdout)
    meta_payload = holdout[0].meta.get("payload")
    payload = Payload(float(meta_payload["mass"]), tuple(meta_payload.get("com_flange", (0.0, 0.0, 0.0)))) \
        if isinstance(meta_payload, dict) and meta_payload.get("mass") else None
    try:
        desc = holdout[0].meta.get("robot_description")
        true_robot = robot_from_dict(desc) if isinstance(desc, dict) else load_robot(holdout[0].meta["robot"])
    except (DescriptionError, FileNotFoundError, KeyError):
        return None                                   # the twin's robot cannot be rebuilt: no truth to compare with
    n = model.robot.n
    named = set(att.top(len(att.steps) + len(att.noise) + 8))
    fams = [f for f, (names, _) in FAMILIES.items() if named & set(names)]
    params = _final_params(att)
    rows, notes = [], []
    for family, step, effect, key, label, unit, scale in _PARAMETERS:
        if effect not in effects or key not in effects[effect]:
            continue
        truth = effects[effect][key] * scale
        fitted, ci = np.full(n, np.nan), np.full(n, np.nan)
        if step in params:
            theta, half, pnames = params[step]
            idx = [i for i, nm in enumerate(pnames) if nm.split("[")[0] == key]
            if len(idx) == n:
                fitted, ci = theta[idx] * scale, half[idx] * scale
        rows.append(ParameterRow(family, label, unit, truth, fitted, ci))
    if "ripple" in effects:
        truth = np.hypot(effects["ripple"]["sin_amplitude"], effects["ripple"]["cos_amplitude"])
        fitted = np.full(n, np.nan)
        if "ripple" in params:
            theta = params["ripple"][0]
            fitted = np.hypot(theta[:n], theta[n:2 * n])
        rows.append(ParameterRow("ripple", "amplitude", "N·m", truth, fitted, np.full(n, np.nan)))
    if "torque_noise" in effects:
        found = next((f for f in att.noise if f.name == "torque_noise"), None)
        fitted = np.where(found.rms > 0, found.rms, np.nan) if found is not None else np.full(n, np.nan)
        rows.append(ParameterRow("torque noise", "σ", "N·m", effects["torque_noise"]["std"], fitted,
                                 np.full(n, np.nan)))
        notes.append("torque noise σ is reported on the joints whose remaining residual is white, or structured only "
                     "within the conditioning error with a white raw τ floor; elsewhere —")
    if payload is not None:
        fitted = np.array([params["payload"][0][0]]) if "payload" in params else np.array([np.nan])
        rows.append(ParameterRow("payload", "mass", "kg", np.array([payload.mass]), fitted, np.array([np.nan])))
    comp = TruthComparison(_present(effects, true_robot, model, payload), sorted(fams, key=list(FAMILIES).index),
                           rows, notes=notes)
    if "rigid body" in comp.present:
        # a sensor gain error scales the (mostly gravity) torque like an inertial error does: the two are compared
        # together, the true Δτ_rbd + g·τ_J against the fitted correction + the fitted gain·τ (if named)
        r = holdout[0]
        q, qd, qdd = r.truth["q_true"], r.truth["qd"], r.truth["qdd"]
        tau_model = inverse_dynamics(model.robot, q, qd, qdd)
        d_true = inverse_dynamics(true_robot, q, qd, qdd) - tau_model
        if "sensor_offset_gain" in effects and "tau_J_true" in r.truth:
            d_true = d_true + effects["sensor_offset_gain"]["gain"] * r.truth["tau_J_true"]
        fit = _rigid_correction(params["rigid_body"][2], params["rigid_body"][0], model.robot, q, qd, qdd) \
            if "rigid_body" in params else np.zeros_like(d_true)
        if "sensor_gain" in params:
            fit = fit + params["sensor_gain"][0][:n] * tau_model
        comp.rigid_true_rms = np.sqrt((d_true ** 2).mean(axis=0))
        comp.rigid_left_rms = np.sqrt(((d_true - fit) ** 2).mean(axis=0))
    return comp


def truth_summary(comp: TruthComparison) -> dict[str, Any]:
    """JSON-able summary (families present / named, parameter rows as lists)."""
    return {"present": comp.present, "named": comp.named,
            "rows": [{"family": r.family, "parameter": r.parameter, "unit": r.unit, "truth": r.truth.tolist(),
                      "fitted": [None if not np.isfinite(x) else float(x) for x in r.fitted]} for r in comp.rows]}
