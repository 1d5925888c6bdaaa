"""The joint-effect library: one class per effect that spoils a torque-sensing joint, each able to *simulate* its
additive contribution to the measured link-side torque τ_J (vectorised over samples and joints) and to be *fitted*
(flat parameter vector + bounds for nonlinear least squares, a regressor for the linear ones).

Convention (DESIGN.md, thesis eq. 3.5–3.6): ``τ_J = τ_rbd(q, q̇, q̈) + Σ visible contributions − Jᵀ f_ext``. Every
effect's :meth:`JointEffect.torque` returns its ``[N, n]`` contribution in N·m; motor-side effects contribute zero to
τ_J (they are hidden behind the sensor and show up only through the motion).

Effects, their place, and where their twin magnitudes come from (``proprio/configs/iiwa14_twin.yaml``):

============================ ======= =============================================================================
effect (YAML key)             place   model / calibration source
============================ ======= =============================================================================
``viscous_coulomb``           link    ``F_v q̇ + F_c tanh(q̇/v_s)``; identified iiwa14 set (Coulomb 0.03–0.32 N·m,
                                      viscous 0.10–0.37 N·m·s/rad, ``proprio/robots/iiwa14_identified.yaml``)
``stribeck``                  link    extra static friction ``F_s exp(−(q̇/v_st)²) tanh(q̇/v_s)``; low-speed
                                      friction of harmonic drives (not in the thesis; off in the calibrated twin)
``load_friction``             link    load-dependent Coulomb friction ``(F_c0 + k|τ_J|) tanh(q̇/v_s)``: a harmonic
                                      drive's Coulomb level grows with the link torque it transmits (Hamon &
                                      Gautier; Wolf & Iskandar: k of a few %; off in the calibrated twin)
``presliding``                link    pre-sliding friction of the drive: the Dahl law of ``hysteresis`` over
                                      tenths of a degree of travel since the last reversal, rate-independent
                                      (``proprio.effects.dahl``; off in the calibrated twin, whose τ_J is a
                                      link-side sensor's: offered to the diagnosis for drive torques)
``hysteresis``                sensor  Dahl law in the reversal-travel domain, saturating ≈95 % after 6° (§2.1,
                                      Fig. 2.5); amplitude scaled with load on joints 2/4
``lost_motion``               sensor  a ≈1° window after each reversal in which the direction-dependent torque
                                      has not flipped yet (§4 intro, "absent changes ... of approximately 1°")
``ripple``                    sensor  harmonic-drive ripple ``A sin(h·N·q + φ)``: frequency ``h·N·q̇/2π`` follows
                                      joint speed (§6); amplitude chosen so raw τ is visibly noisy at 10 % speed
``sensor_offset_gain``        sensor  ``g·τ + o``; offsets 0.1–0.9 N·m (DESIGN.md), gain error ≈1 %
``torque_noise``              sensor  white Gaussian noise σ; "significant torque noise" at 10 % speed (Fig. 2.5)
``encoder_noise``             sensor  position noise + quantisation of q (no torque contribution)
(:class:`Motor`)              motor   reflected motor inertia B and motor friction, hidden behind the sensor;
                                      the twin's ``drive`` block, not an ``EFFECTS`` entry (nothing to fit in τ_J)
``elasticity``                motor   series elastic drive (K, D) with the motor's state, simulated by
                                      ``proprio.systems.joint_drive``; zero direct contribution to τ_J
``offset_drift``              sensor  time-varying: offset ``o0 + Δo(1 − exp(−t/T))`` on the session clock
                                      (thermal drift after switch-on; off in the calibrated twin)
``friction_warmup``           link    time-varying: cold-gearbox excess friction ``exp(−t/T)(F_v q̇ + F_c tanh)``
                                      fading as the joint warms up (off in the calibrated twin)
============================ ======= =============================================================================

Every friction (``viscous_coulomb``, ``stribeck``, ``friction_warmup``, the motor's, a robot description's
``friction`` block via :func:`robot_friction`) is the one law of :mod:`proprio.friction_law`, with its one default
smoothing ``v_s`` (:data:`proprio.friction_law.SMOOTH_VELOCITY`, overridable per effect by ``smooth_velocity``).

Time-varying effects (class attribute ``time_varying = True``) read the *session clock* ``MotionSignals.t``: the
twin adds its config's ``session_time_s`` to the run's time, the diagnosis each recording's
``meta["session_time_s"]`` (:mod:`proprio.effects.time_varying`).

Effects beyond this library are *plugins*: a :class:`JointEffect` subclass in any module, named by its dotted path
``"package.module:Class"`` in an ``effects:`` mapping or a diagnosis candidate list once the user consented to it
(an entry point of the group ``proprio.effects``, ``--allow-plugin``, :func:`register_plugin`; a name alone never
imports anything: :mod:`proprio.effects.plugins`, :func:`resolve_effect`); :mod:`proprio.effects.open_world` ships
four, which the gap benchmark reaches only that way.

Hysteresis, pre-sliding friction and lost motion share one state, the *reversal travel* ``r`` (signed joint travel since the last
direction reversal, :func:`reversal_travel`) — the quantity behind the thesis' feature ``r`` (§4.2), which the learning
stack encodes causally with a position deadband and ±10° clipping in :mod:`proprio.learning.features`. Reversals are detected
with a velocity deadband (Schmitt trigger on q̇) so that noise around standstill does not create spurious reversals;
the travel is measured from the extremum of q reached before the reversal. Stateful effects are evaluated per
segment between reversals; the values carried across segments follow an affine recursion, run once per reversal
(the reversal travel and this recursion are numba kernels; no per-sample Python loop). A motion can be taken in
pieces with the reversal state carried between them (:class:`proprio.effects.sensor_chain.PathEffects`): the twin's
Diagram applies its sensors so, once per block of samples, and the pieces give the whole motion's values (tests).
"""
from __future__ import annotations

from proprio.effects.base import EffectConfigError, JointEffect
from proprio.effects.dahl import PreSliding
from proprio.effects.drive import Elasticity, Motor
from proprio.effects.friction import LoadFriction, SmoothFriction, Stribeck, ViscousCoulomb, robot_friction
from proprio.effects.hysteresis import Hysteresis, LostMotion
from proprio.effects.plugins import allow_plugins, effect_key, register_plugin, resolve_effect
from proprio.effects.registry import EFFECTS
from proprio.effects.schema import make_effects
from proprio.effects.sensor import EncoderNoise, Ripple, SensorOffsetGain, TorqueNoise
from proprio.effects.time_varying import FrictionWarmup, OffsetDrift

__all__ = ["JointEffect", "EffectConfigError", "SmoothFriction", "ViscousCoulomb", "Stribeck",
           "LoadFriction", "robot_friction", "Hysteresis", "PreSliding",
           "LostMotion", "Ripple", "SensorOffsetGain", "TorqueNoise", "EncoderNoise", "Motor", "Elasticity",
           "OffsetDrift", "FrictionWarmup", "EFFECTS", "make_effects", "resolve_effect", "effect_key", "register_plugin",
           "allow_plugins"]
