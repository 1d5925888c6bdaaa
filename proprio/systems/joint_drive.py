"""The joint drive: motor torque command → torque acting on the links, with the motor side (motor inertia and
friction, series elasticity: hidden behind the torque sensor) and the link-side friction (visible in τ_J).

Three Systems implement it with one law (:class:`DriveLaw`: what the drive does to the sensed torque), chosen by
:func:`AddJointDrive`:

* :class:`FrictionDrive` — the common case (rigid, link-side friction on q̇ alone: every shipped iiwa twin): Drake C++
  systems evaluating the effects' own friction code, traced once into symbolic expressions
  (``actuation = τ_m − τ_f,m − τ_f,link(q̇)``, the motor's friction on the motor velocities ``C q̇`` when coupled);
  ≈ 5 µs per step;
* :class:`CoupledDrive` — a rigid drive whose coupled motors put rotor inertia off the diagonal (the TX40's wrist):
  the friction stage above, Drake's compiled ``InverseDynamics`` for the bias, and one thin Python System
  (:class:`CoupledRotorInertia`) for the one thing no compiled primitive of the pip wheel does, the solve with the
  configuration-dependent ``M(q) + CᵀI_aC`` (:func:`coupled_actuation`); ≈ 20 µs per step (the TX40 twin: 34 µs
  per 0.1 ms step, 17 µs with its coupling dropped, ``benchmarks/bench_twin.py --coupled``);
* :class:`JointDrive` — one Python ``LeafSystem`` for everything else (elastic, pre-sliding, time-varying or
  user-plugin link effects), vectorised over joints (≈ 25 µs per step):

* **rigid drive** (no ``elasticity`` effect): θ = q. The reflected motor inertia B of the :class:`Motor` (the
  twin's ``drive`` block) is Drake's rotor inertia in the plant (implicit, exact); the drive applies
  ``u = τ_m − τ_f,m(q̇) − τ_f,link(q̇)`` and the sensor sees ``τ_J = τ_m − τ_f,m − B q̈ = u + τ_f,link − B q̈``.
* **elastic drive** (``elasticity`` + :class:`Motor`, thesis eq. 3.6): discrete motor state ``[θ, θ̇]`` (rad, rad/s),
  ``B θ̈ = τ_m − τ_f,m(θ̇) − τ_s``. The spring ``τ_s = K(θ − q) + D(θ̇ − q̇)`` is Drake's implicit PD-controlled
  actuator (SAP): the drive feeds ``[θ; θ̇]`` to the plant's desired-state input with gains (K, D), so a realistic
  stiffness on light links is stable at 1 ms; the feed-forward actuation is ``−τ_f,link(q̇)``. The motor state is
  advanced with semi-implicit Euler from the spring torque the plant applied in the same step (its net actuation),
  so action equals reaction. The sensor sees ``τ_J = τ_s``. The controller feeds back the motor state (collocated,
  like the iiwa's motor encoders): PD on the link position through the spring is the classic unstable
  non-collocated loop.

Link-side effects other than the library's friction (user plugins, :mod:`proprio.effects.plugins`) act like the
friction: each step the drive evaluates their ``torque`` on the current state ``(t, q, q̇)`` with ``q̈ = 0`` and no
torque (a link-side effect may depend on t, q and q̇ only) and subtracts it from the actuation. Their time is the
session clock, the context time plus ``session_time_s`` [s] (a time-varying friction such as ``friction_warmup``
reads it). Pre-sliding friction (:class:`~proprio.effects.PreSliding`) depends on the travel since the last
reversal: the drive keeps its reversal state as discrete state and applies the per-step form of its law.

**Load-dependent friction** (:class:`~proprio.effects.LoadFriction`, ``(F_c0 + k|τ_load|) sgn_s(q̇)``) needs the
torque the gear transmits in the step: the drive takes it as the command past the motor's friction,
``τ_load = τ_m − τ_f,m(q̇)`` (τ_J without the rotor's inertial torque ``B q̈``, the step's result; an input of the
step, so no algebraic loop). The twin recovers it from the logged net actuation with
:func:`proprio.friction_law.load_from_net` (:meth:`DriveLaw.transmitted_load`). Rigid drives only.

Either way the plant's net actuation ``u`` satisfies ``τ_J = u + τ_f,link [− B q̈ for the rigid drive]``, and the link
dynamics give ``τ_J = τ_rbd(q, q̇, q̈) + τ_f,link − Jᵀ f_ext``; the twin recovers the true τ_J from the logged net
actuation and the motion (:meth:`JointDrive.sensed_torque`).

A robot description with a ``drive`` block (:mod:`proprio.drive_description`) gives the twin its motor side when the
twin config has no ``drive`` block (:func:`motor_from_description`: rotor inertia → ``motor_inertia``, motor friction;
:func:`coupling_from_description`: the normalised coupling C of a coupled drive). When its τ is a drive torque
(``tau_kind: drive``), the rigid drive senses what the motor delivers instead of τ_J:
``τ = τ_m + τ_0 = u + τ_f,link + τ_f,m + O q̈ + τ_0`` (rotor inertia and motor friction included, constant drive
offsets ``τ_0``; O below).

**Coupled drives** (a motor turning with several joints, e.g. the TX40's motor 6 with joints 5 and 6, ``v = C q̇``):
the joints see the rotor inertia ``CᵀI_aC`` and the motor friction ``Cᵀτ_f,m(C q̇)``. Drake's rotor inertia is per
actuator (a diagonal term of the mass matrix; Drake has no coupled-actuator mechanism), so the plant carries the
diagonal ``D = diag(CᵀI_aC)`` and the drive the off-diagonal rest ``O = CᵀI_aC − D``, *implicitly*: an explicit
``−O q̈`` from the last step would lag by one step (an error ~``O·dt·dq̈/dt``: all compiled, that way the TX40 twin
runs 1.8× faster but its τ moves by up to 1.3 N·m on a fast 0.4 s motion) and can be unstable. Each step the
:class:`CoupledDrive` solves the arm's full dynamics at the step's state with a continuous copy of the plant
(``model_plant``: same URDF, payload and diagonal rotor inertia): ``q̈* = (M(q) + D + O)⁻¹(τ_m − τ_f − b(q, q̇))``,
``b = ID(q, q̇, 0)`` with gravity (Drake's ``InverseDynamics`` System), and applies ``u = τ_m − τ_f − O q̈*``. The
discrete plant (TAMSI, no contact) then steps ``(M + D) q̈ = u − b`` with the same M and b, so its q̈ is q̈* exactly:
the twin moves as the arm with ``M + CᵀI_aC`` (tests: τ equals the regressor's drive law to 1e-9 N·m). A coupled
drive must be rigid (no ``elasticity``). The solve needs ``M(q)`` at every step, and no compiled primitive of the
pip wheel solves with it (Drake's forward dynamics is the plant's own step, on its own state), so
:class:`CoupledRotorInertia` is the one per-step Python System; everything else of the drive is compiled.

Friction acts explicitly (from the state at the start of the step): stable while ``(c_j / m)·dt < 2`` with ``c_j`` the
friction slope ``F_v + F_c/v_s (+ F_s/v_s)`` (minus the spring's implicit damping D when elastic) and ``m`` the
smallest inertia the joint's torque sees along the trajectory; the motor side of the elastic drive while
``(K/B)·dt² + 2(D/B)·dt < 2``.
:func:`check_explicit_friction` and :func:`check_elastic_stability` refuse violations with a 2× margin.
"""
from __future__ import annotations

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.symbolic import MakeVectorVariable
from pydrake.systems.framework import BasicVector, Context, Diagram, DiagramBuilder, DiscreteValues, LeafSystem
from pydrake.systems.controllers import InverseDynamics
from pydrake.systems.primitives import Adder, ConstantVectorSource, SymbolicVectorSystem
from scipy.linalg import lapack

from proprio import friction_law
from proprio.description import RobotDescription
from proprio.effects import Elasticity, JointEffect, LoadFriction, Motor, PreSliding, Stribeck, ViscousCoulomb
from proprio.effects.dahl import DahlState
from proprio.signals import MotionSignals

__all__ = ["DriveLaw", "JointDrive", "FrictionDrive", "CoupledDrive", "CoupledRotorInertia", "coupled_actuation",
           "friction_only", "AddJointDrive", "check_explicit_friction",
           "check_elastic_stability", "friction_slope", "motor_from_description", "coupling_from_description",
           "reflected_inertia"]


def motor_from_description(desc: RobotDescription) -> Motor | None:
    """The twin's motor side from ``desc.drive`` (reflected rotor inertia and motor friction per motor, in joint
    units), ``None`` without a drive block. A coupled drive also needs :func:`coupling_from_description`."""
    drive = desc.drive
    if drive is None:
        return None
    return Motor(desc.n, motor_inertia=np.array(drive.rotor_inertia), motor_viscous=np.array(drive.motor_viscous),
                 motor_coulomb=np.array(drive.motor_coulomb))


def coupling_from_description(desc: RobotDescription) -> np.ndarray | None:
    """The normalised coupling ``C [n, n]`` of a coupled drive block (motor velocities ``v = C q̇`` in joint units,
    :attr:`~proprio.drive_description.DriveDescription.normalized_coupling`), ``None`` for none or an uncoupled one."""
    drive = desc.drive
    return drive.normalized_coupling if drive is not None and drive.coupled else None


def reflected_inertia(motor: Motor, coupling: np.ndarray | None = None) -> np.ndarray:
    """The rotor inertia the joints see, ``Cᵀ diag(I_a) C [n, n]`` [kg·m²] (``diag(I_a)`` when uncoupled)."""
    c = np.eye(motor.n) if coupling is None else np.asarray(coupling, dtype=float)
    return c.T @ (motor.motor_inertia[:, None] * c)


def friction_slope(link_effects: list[JointEffect], motor: Motor | None = None,
                   coupling: np.ndarray | None = None, max_load: np.ndarray | None = None) -> np.ndarray:
    """Largest ``∂τ_f/∂q̇`` [N·m·s/rad] per joint of the velocity-dependent friction (at q̇ = 0; for other link-side
    effects, e.g. plugins, the central difference ``|∂τ_j/∂q̇_j|`` at q = 0, q̇ = 0 with a 1e-4 rad/s step). A
    coupled motor's friction (normalised ``coupling`` C) adds the diagonal of ``Cᵀ diag(s_m) C``. A load-dependent
    friction's level is taken at the load ``max_load`` [N·m] per joint (the joints' effort limits; required then)."""
    slope = 0.0
    for eff in link_effects:
        if isinstance(eff, ViscousCoulomb):
            slope = slope + friction_law.slope_at_rest(eff.viscous, eff.coulomb, eff.smooth_velocity)
        elif isinstance(eff, LoadFriction):
            if max_load is None:
                raise ValueError("friction_slope: load_friction needs max_load (the joints' effort limits)")
            slope = slope + friction_law.slope_at_rest(0.0, eff.coulomb + eff.load_gain * np.asarray(max_load),
                                                       eff.smooth_velocity)
        elif isinstance(eff, Stribeck):
            slope = slope + friction_law.slope_at_rest(0.0, eff.static, eff.smooth_velocity)
        else:
            slope = slope + _numeric_slope(eff)
    if motor is not None:
        s_m = friction_law.slope_at_rest(motor.motor_viscous, motor.motor_coulomb, motor.smooth_velocity)
        slope = slope + (s_m if coupling is None else (np.asarray(coupling) ** 2).T @ s_m)
    return np.asarray(slope, dtype=float)


def _numeric_slope(eff: JointEffect, h: float = 1e-4) -> np.ndarray:
    """``|∂τ_j/∂q̇_j|`` [N·m·s/rad] per joint of a link-side effect at q = 0, q̇ = 0 (one batch of 2n samples)."""
    n = eff.n
    qd = np.concatenate([h * np.eye(n), -h * np.eye(n)])
    z = np.zeros_like(qd)
    tau = eff.torque(MotionSignals(np.zeros(2 * n), z, qd, z))
    return np.abs(np.diag(tau[:n]) - np.diag(tau[n:])) / (2 * h)


def check_explicit_friction(slope: np.ndarray, inertia: np.ndarray, time_step: float) -> None:
    """Raise ``ValueError`` when explicit friction of slope ``slope`` [N·m·s/rad] on inertia ``inertia`` [kg·m²]
    would make the discrete twin unstable (2× margin)."""
    ratio = np.asarray(slope) * time_step / np.asarray(inertia)
    if np.any(ratio > 1.0):
        j = int(np.argmax(ratio))
        raise ValueError(f"friction of joint {j + 1} is too stiff for time_step {time_step:g} s (slope·dt/inertia = "
                         f"{ratio[j]:.2f} > 1): raise smooth_velocity, add motor inertia or lower the Coulomb level")


def check_elastic_stability(elasticity: Elasticity, motor: Motor, time_step: float) -> None:
    """Raise ``ValueError`` when the explicit motor side of the elastic drive would be unstable:
    require ``(K/B)·dt² + 2·(D/B)·dt < 1`` (stable below 2; a 2× margin). The link side is implicit (SAP)."""
    b = motor.motor_inertia
    index = elasticity.stiffness / b * time_step ** 2 + 2.0 * elasticity.damping / b * time_step
    if np.any(index >= 1.0):
        j = int(np.argmax(index))
        raise ValueError(f"elasticity of joint {j + 1} is too stiff/damped for time_step {time_step:g} s with motor "
                         f"inertia {b[j]:.4f} kg·m² ((K/B)·dt² + 2(D/B)·dt = {index[j]:.2f} >= 1): lower "
                         "stiffness/damping, raise motor_inertia or lower the time step")


class DriveLaw:
    """What the drive does to the measured torque, shared by the drive Systems (:class:`JointDrive`,
    :class:`FrictionDrive`): the link-side effects, the motor side and, for a drive-torque arm, its offsets.
    The twin recovers the true τ from the logged net actuation with :meth:`sensed_torque`."""

    def _set_law(self, n: int, link_effects: list[JointEffect], motor: Motor | None, elasticity: Elasticity | None,
                 session_time_s: float, drive_offset: np.ndarray | None, coupling: np.ndarray | None) -> None:
        for eff in link_effects:
            if eff.place != "link":
                raise ValueError(f"JointDrive: {eff.name} is not a link-side effect (place {eff.place!r})")
        if elasticity is not None and (motor is None or np.any(motor.motor_inertia <= 0)):
            raise ValueError("JointDrive: an elastic drive needs a motor with motor_inertia > 0")
        if drive_offset is not None and elasticity is not None:
            raise ValueError("JointDrive: drive-torque sensing (drive_offset) needs a rigid drive")
        if coupling is not None and (motor is None or elasticity is not None):
            raise ValueError("JointDrive: a coupled drive needs a motor and a rigid drive (no elasticity)")
        if elasticity is not None and any(isinstance(e, LoadFriction) for e in link_effects):
            raise ValueError("JointDrive: load_friction needs a rigid drive (its load is the transmitted torque)")
        self.drive_offset = None if drive_offset is None else np.asarray(drive_offset, dtype=float)
        self.n = n
        self.link_effects = list(link_effects)
        self.motor = motor
        self.elasticity = elasticity
        self.session_time_s = float(session_time_s)
        self.coupling = None if coupling is None else np.asarray(coupling, dtype=float)
        # rotor inertia: its diagonal is Drake's (the plant's rotor inertia), the rest acts through the drive
        reflected = np.zeros((n, n)) if motor is None else reflected_inertia(motor, self.coupling)
        self.rotor_diagonal = np.diag(reflected).copy()
        self._off = reflected - np.diag(self.rotor_diagonal)

    def motor_friction(self, qd: np.ndarray) -> np.ndarray:
        """The rigid drive's motor friction at the joints [N·m] ``[N, n]`` (or ``[n]``) for link velocities ``qd``
        [rad/s]: ``Cᵀ τ_f,m(C q̇)`` on the motor velocities ``v = C q̇`` (``τ_f,m(q̇)`` uncoupled)."""
        if self.motor is None:
            return np.zeros_like(qd)
        if self.coupling is None:
            return self.motor.friction(qd)
        return self.motor.friction(np.asarray(qd) @ self.coupling.T) @ self.coupling

    def link_torque(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray, load: np.ndarray | None = None
                    ) -> np.ndarray:
        """τ_link [N·m] ``[N,n]`` at run times ``t`` [s] ``[N]`` (the effects see the session clock ``t +
        session_time_s``) and states ``q``, ``qd`` ``[N,n]``: the sum of the link-side effects (friction and plugins),
        evaluated as the drive applies them (q̈ = 0); ``load`` [N·m] ``[N,n]``: the transmitted torque a
        load-dependent friction needs (:meth:`transmitted_load`)."""
        s = MotionSignals(np.asarray(t, dtype=float) + self.session_time_s, q, qd, np.zeros_like(qd), load)
        out = np.zeros_like(qd)
        for eff in self.link_effects:
            out = out + eff.torque(s)
        return out

    def transmitted_load(self, net_actuation: np.ndarray, t: np.ndarray, q: np.ndarray, qd: np.ndarray,
                         qdd: np.ndarray) -> np.ndarray | None:
        """The load ``τ_m − τ_f,m(q̇)`` [N·m] ``[N,n]`` the load-dependent frictions saw in each step (module
        docstring), recovered from the logged net actuation ``f = τ_m − τ_f,m − τ_link`` (plus ``O q̈`` of a coupled
        rotor inertia) with :func:`proprio.friction_law.load_from_net`; ``None`` without such a friction."""
        loaded = [e for e in self.link_effects if isinstance(e, LoadFriction)]
        if not loaded:
            return None
        s = MotionSignals(np.asarray(t, dtype=float) + self.session_time_s, q, qd, np.zeros_like(qd))
        other = sum((e.torque(s) for e in self.link_effects if not isinstance(e, LoadFriction)), np.zeros_like(qd))
        sign = friction_law.smooth_sign(qd, loaded[0].smooth_velocity)
        if any(np.any(e.smooth_velocity != loaded[0].smooth_velocity) for e in loaded):
            raise ValueError("JointDrive: several load_friction effects need one smooth_velocity")
        c0, k = sum(e.coulomb for e in loaded), sum(e.load_gain for e in loaded)
        return friction_law.load_from_net(net_actuation + qdd @ self._off + other + c0 * sign, sign, k)

    def sensed_torque(self, net_actuation: np.ndarray, t: np.ndarray, q: np.ndarray, qd: np.ndarray,
                      qdd: np.ndarray, tau_link: np.ndarray | None = None) -> np.ndarray:
        """True τ_J ``[N,n]`` from the plant's logged net actuation and link motion (``u + τ_link``, minus
        ``B q̈`` for the rigid drive whose motor inertia the plant carries as rotor inertia); with ``drive_offset``
        (a drive-torque arm) the motor's torque ``u + τ_link + τ_f,m(q̇) + τ_0`` instead. ``tau_link``: τ_link
        already evaluated (a piece of a motion with the reversal state carried), else :meth:`link_torque`."""
        if tau_link is None:
            tau_link = self.link_torque(t, q, qd, self.transmitted_load(net_actuation, t, q, qd, qdd))
        if self.drive_offset is not None:
            return net_actuation + tau_link + self.drive_offset + self.motor_friction(qd) + qdd @ self._off
        return self.rigid_body_torque(net_actuation, qdd) + tau_link

    def rigid_body_torque(self, net_actuation: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """``τ_rbd = M(q) q̈ + C(q, q̇) q̇ − τ_g(q)`` [N·m] ``[N,n]`` of the simulated arm (payload included) from the
        plant's logged net actuation and acceleration: the plant steps ``(M + D) q̈ = u − b`` with the rotor inertia
        ``D`` it carries (:attr:`rotor_diagonal` for a rigid drive, none for the elastic one, whose spring torque is
        part of ``u``), so ``τ_rbd = u − D q̈`` — the arm's own dynamics in the step, without re-evaluating them."""
        if self.elasticity is not None:
            return np.array(net_actuation, dtype=float)
        return net_actuation - self.rotor_diagonal * qdd

    def set_motor_state(self, context: Context, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> None:
        """Start the drive in equilibrium with link state (q, q̇) carrying torque ``tau`` (a no-op for a rigid
        drive; see :meth:`JointDrive.set_motor_state`)."""


class FrictionDrive(DriveLaw, Diagram):
    """The rigid drive whose per-step work is friction on q̇ alone (link-side ``viscous_coulomb`` and ``stribeck``, the
    motor's friction, on the motor velocities ``C q̇`` when ``coupling`` C is given), as Drake C++ systems:
    ``actuation = motor_torque − τ_f(q̇)``.

    ``τ_f`` is the effects' own ``friction`` code (:mod:`proprio.friction_law`) evaluated once on symbolic velocities
    at construction; a stateless ``SymbolicVectorSystem`` evaluates those expressions each step (≈ 5 µs instead of
    ≈ 25 µs for the Python :class:`JointDrive`) and an ``Adder`` applies them. Ports as :class:`JointDrive`:
    ``motor_torque`` [n] N·m, ``link_state`` [2n] = [q; q̇] → ``actuation`` [n] N·m. For discrete Diagrams like the
    twin's (Drake's stateless SymbolicVectorSystem refuses to be asked for time derivatives). A coupling whose rotor
    inertia ``CᵀI_aC`` is not diagonal needs :class:`CoupledDrive`, which runs this drive as its friction stage.
    """

    def __init__(self, n: int, link_effects: list[JointEffect], motor: Motor | None = None,
                 session_time_s: float = 0.0, drive_offset: np.ndarray | None = None,
                 coupling: np.ndarray | None = None):
        Diagram.__init__(self)
        self._set_law(n, link_effects, motor, None, session_time_s, drive_offset, coupling)
        if not friction_only(link_effects, None):
            raise ValueError("FrictionDrive: link-side effects other than viscous_coulomb/stribeck need JointDrive")
        if np.any(self._off != 0.0):
            raise ValueError("FrictionDrive: a coupled rotor inertia off the diagonal needs CoupledDrive")
        x = MakeVectorVariable(2 * n, "x")
        with np.errstate(invalid="ignore"):     # Drake's symbolic arithmetic can leave the FPU's invalid flag set
            tau_f = self.motor_friction(x[n:])
            for eff in link_effects:
                tau_f = tau_f + eff.friction(x[n:])
            minus_tau_f = -tau_f
        builder = DiagramBuilder()
        friction = builder.AddNamedSystem("friction", SymbolicVectorSystem(input=x, output=minus_tau_f))
        adder = builder.AddNamedSystem("apply", Adder(2, n))
        builder.Connect(friction.get_output_port(), adder.get_input_port(1))
        builder.ExportInput(adder.get_input_port(0), "motor_torque")
        builder.ExportInput(friction.get_input_port(), "link_state")
        builder.ExportOutput(adder.get_output_port(), "actuation")
        builder.BuildInto(self)


def friction_only(link_effects: list[JointEffect], elasticity: Elasticity | None) -> bool:
    """Whether a drive's friction stage is a :class:`FrictionDrive`: rigid, and its link-side effects are the
    library's velocity friction (``viscous_coulomb``, ``stribeck``: functions of q̇ alone)."""
    return elasticity is None and all(type(e) in (ViscousCoulomb, Stribeck) for e in link_effects)


def coupled_actuation(mass: np.ndarray, off: np.ndarray, force: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """The actuation [N·m] ``[n]`` that makes a plant with mass matrix ``mass`` = ``M(q) + D`` (the diagonal rotor
    inertia D its actuators carry) move as the arm with ``M(q) + D + off`` (``off`` = O, the off-diagonal rest of
    ``CᵀI_aC``) does, implicitly in the same step: ``q̈* = (M + D + O)⁻¹(f − b)``, ``u = f − O q̈*``, for the
    generalized force ``force`` = f = ``τ_m − τ_f`` and the bias ``bias`` = b = ``ID(q, q̇, 0)`` (gravity applied) of
    the step's state. The plant's own step ``(M + D) q̈ = u − b`` then gives q̈ = q̈*."""
    _, qdd, info = lapack.dposv(mass + off, force - bias)         # Cholesky: M + CᵀI_aC is SPD
    if info != 0:
        raise np.linalg.LinAlgError(f"coupled_actuation: M(q) + CᵀI_aC is not positive definite (LAPACK info {info})")
    return force - off @ qdd


class CoupledRotorInertia(LeafSystem):
    """The implicit off-diagonal rotor inertia of a coupled drive (:func:`coupled_actuation`), the per-step Python
    part of :class:`CoupledDrive`. Input ports ``force`` [n] N·m (``τ_m − τ_f``), ``bias`` [n] N·m (``ID(q, q̇, 0)``
    of ``model_plant``), ``link_state`` [2n] = [q; q̇]; output ``actuation`` [n] N·m. ``model_plant``: a continuous
    plant of the twin's arm with the diagonal rotor inertia, evaluated on its own context for ``M(q) + D``;
    ``off``: O [n, n] kg·m²."""

    def __init__(self, model_plant: MultibodyPlant, off: np.ndarray):
        LeafSystem.__init__(self)
        n = model_plant.num_velocities()
        self._plant, self._ctx, self._off = model_plant, model_plant.CreateDefaultContext(), np.asarray(off, float)
        self._force = self.DeclareVectorInputPort("force", n)
        self._bias = self.DeclareVectorInputPort("bias", n)
        self._link = self.DeclareVectorInputPort("link_state", 2 * n)
        self.DeclareVectorOutputPort("actuation", n, self._calc,
                                     prerequisites_of_calc={self._force.ticket(), self._bias.ticket(),
                                                            self._link.ticket()})

    def _calc(self, context: Context, output: BasicVector) -> None:
        self._plant.SetPositions(self._ctx, self._link.Eval(context)[:self._plant.num_positions()])
        output.SetFromVector(coupled_actuation(self._plant.CalcMassMatrix(self._ctx), self._off,
                                               self._force.Eval(context), self._bias.Eval(context)))


class CoupledDrive(DriveLaw, Diagram):
    """A rigid drive with coupled motors whose rotor inertia ``CᵀI_aC`` is not diagonal (``coupling`` C, normalised,
    n×n; module docstring): the friction stage (a :class:`FrictionDrive` with the coupled motor friction, or the
    Python :class:`JointDrive` for other link-side effects) gives ``f = τ_m − τ_f``, Drake's ``InverseDynamics`` on
    ``model_plant`` the bias ``b = ID(q, q̇, 0)``, and :class:`CoupledRotorInertia` the actuation
    ``u = f − O q̈*``. ``model_plant``: a continuous plant of the twin's arm with the diagonal rotor inertia
    :attr:`rotor_diagonal`. Ports as :class:`JointDrive`: ``motor_torque`` [n], ``link_state`` [2n] → ``actuation``
    [n]."""

    def __init__(self, n: int, link_effects: list[JointEffect], motor: Motor, coupling: np.ndarray,
                 model_plant: MultibodyPlant, time_step: float = 1e-3, session_time_s: float = 0.0,
                 drive_offset: np.ndarray | None = None):
        Diagram.__init__(self)
        self._set_law(n, link_effects, motor, None, session_time_s, drive_offset, coupling)
        # the friction stage applies the motor's friction; the rotor inertia is the plant's (D) and this Diagram's (O)
        friction_motor = Motor(n, motor_inertia=np.zeros(n), motor_viscous=motor.motor_viscous,
                               motor_coulomb=motor.motor_coulomb, smooth_velocity=motor.smooth_velocity)
        builder = DiagramBuilder()
        if friction_only(link_effects, None):
            stage = FrictionDrive(n, link_effects, friction_motor, session_time_s, coupling=coupling)
        else:
            stage = JointDrive(n, link_effects, friction_motor, None, time_step, session_time_s, coupling=coupling)
        builder.AddNamedSystem("friction", stage)
        bias = builder.AddNamedSystem("bias", InverseDynamics(model_plant,
                                                              InverseDynamics.InverseDynamicsMode.kInverseDynamics))
        rest = builder.AddNamedSystem("no_acceleration", ConstantVectorSource(np.zeros(n)))
        inertia = builder.AddNamedSystem("rotor_inertia", CoupledRotorInertia(model_plant, self._off))
        builder.Connect(rest.get_output_port(), bias.get_input_port_desired_acceleration())
        builder.Connect(stage.GetOutputPort("actuation"), inertia.GetInputPort("force"))
        builder.Connect(bias.get_output_port_generalized_force(), inertia.GetInputPort("bias"))
        builder.ExportInput(stage.GetInputPort("motor_torque"), "motor_torque")
        builder.ExportInput(stage.GetInputPort("link_state"), "link_state")
        builder.ConnectInput("link_state", bias.get_input_port_estimated_state())
        builder.ConnectInput("link_state", inertia.GetInputPort("link_state"))
        builder.ExportOutput(inertia.GetOutputPort("actuation"), "actuation")
        builder.BuildInto(self)


class JointDrive(DriveLaw, LeafSystem):
    """Drive + link friction for ``n`` joints (see the module docstring).

    Input ports: ``motor_torque`` [n] N·m (the controller's command), ``link_state`` [2n] = [q; q̇] (plant state),
    and for the elastic drive ``net_actuation`` [n] N·m (the plant's applied joint torque, to close action/reaction).
    Output ports: ``actuation`` [n] N·m (the plant's actuation input; feed-forward to the implicit spring when
    elastic) and, for the elastic drive, ``motor_state`` [2n] = [θ; θ̇] (the plant's desired state). τ_link is a
    function of the logged t, q, q̇ only, so the twin recomputes it from the log instead of evaluating a second port.
    With a ``coupling`` C (normalised, n×n) it applies the motor's friction on the motor velocities ``C q̇``; a rotor
    inertia ``CᵀI_aC`` off the diagonal needs :class:`CoupledDrive`, which runs this drive as its friction stage.
    """

    def __init__(self, n: int, link_effects: list[JointEffect], motor: Motor | None = None,
                 elasticity: Elasticity | None = None, time_step: float = 1e-3, session_time_s: float = 0.0,
                 drive_offset: np.ndarray | None = None, coupling: np.ndarray | None = None):
        LeafSystem.__init__(self)
        self._set_law(n, link_effects, motor, elasticity, session_time_s, drive_offset, coupling)
        if np.any(self._off != 0.0):
            raise ValueError("JointDrive: a coupled rotor inertia off the diagonal needs CoupledDrive")
        self.time_step = time_step
        # per-step fast path: the viscous + Coulomb frictions acting on q̇ (link side, and an uncoupled motor's for a
        # rigid drive) stacked as rows [k, n] of ONE call of the law (proprio.friction_law, the effects' batch code)
        on_qd = self.link_effects + ([motor] if motor is not None and elasticity is None and coupling is None else [])
        rows = [(e.viscous, e.coulomb, e.smooth_velocity) for e in on_qd if isinstance(e, ViscousCoulomb)]
        rows += [(e.motor_viscous, e.motor_coulomb, e.smooth_velocity) for e in on_qd if isinstance(e, Motor)]
        self._vc = tuple(np.array(col) for col in zip(*rows)) if rows else None      # (F_v, F_c, v_s), each [k, n]
        self._stribeck = [e for e in on_qd if isinstance(e, Stribeck)]
        # pre-sliding friction keeps its reversal state (per-step law of proprio.effects.dahl) as discrete state
        self._presliding = [e for e in self.link_effects if isinstance(e, PreSliding)]
        self._general = [e for e in self.link_effects if not isinstance(e, (ViscousCoulomb, Stribeck, PreSliding))]
        self._loaded = any(isinstance(e, LoadFriction) for e in self._general)
        self._u_motor = self.DeclareVectorInputPort("motor_torque", n)
        self._u_link = self.DeclareVectorInputPort("link_state", 2 * n)
        uses = {self._u_link.ticket()} | ({self.time_ticket()} if self._general else set())
        if elasticity is not None:
            self._u_net = self.DeclareVectorInputPort("net_actuation", n)
            self._state = self.DeclareDiscreteState(2 * n)
            self.DeclarePeriodicDiscreteUpdateEvent(time_step, 0.0, self._update_motor)
            self.DeclareStateOutputPort("motor_state", self._state)
        else:
            uses.add(self._u_motor.ticket())
        if self._presliding:
            self._dahl = self.DeclareDiscreteState(6 * n * len(self._presliding))
            self.DeclarePeriodicDiscreteUpdateEvent(time_step, 0.0, self._update_presliding)
            self.DeclareInitializationDiscreteUpdateEvent(self._start_presliding)
            uses.add(self.discrete_state_ticket(self._dahl))
        self.DeclareVectorOutputPort("actuation", n, self._calc_actuation, prerequisites_of_calc=uses)

    def _presliding_step(self, context: Context) -> tuple[list[DahlState], np.ndarray]:
        """The pre-sliding states advanced by the current link state, and their summed torque [n] N·m."""
        x = self._u_link.Eval(context)
        q, qd = x[:self.n], x[self.n:]
        old = np.split(context.get_discrete_state(self._dahl).value(), len(self._presliding))
        out = [eff.step(DahlState.from_vector(v), q, qd) for eff, v in zip(self._presliding, old)]
        return [st for st, _ in out], np.sum([tau for _, tau in out], axis=0)

    def _start_presliding(self, context: Context, discrete_state: DiscreteValues) -> None:
        x = self._u_link.Eval(context)
        starts = [eff.start(x[:self.n], x[self.n:]).vector() for eff in self._presliding]
        discrete_state.set_value(self._dahl, np.concatenate(starts))

    def _update_presliding(self, context: Context, discrete_state: DiscreteValues) -> None:
        states, _ = self._presliding_step(context)
        discrete_state.set_value(self._dahl, np.concatenate([st.vector() for st in states]))

    def _link_on_state(self, context: Context) -> np.ndarray:
        """Everything acting on the link state in one step: friction on q̇ (link side, plus motor side for a rigid
        drive) and the other link-side effects on (t, q, q̇)."""
        x = self._u_link.Eval(context)
        q, qd = x[:self.n], x[self.n:]
        tau = np.zeros(self.n) if self._vc is None else friction_law.viscous_coulomb(qd, *self._vc).sum(axis=0)
        for eff in self._stribeck:
            tau = tau + eff.friction(qd)
        if self.coupling is not None:
            tau = tau + self.motor_friction(qd)
        if self._presliding:
            tau = tau + self._presliding_step(context)[1]
        if self._general:
            load = None
            if self._loaded:          # the torque the gear transmits: the command past the motor's friction
                load = (self._u_motor.Eval(context) - (self.motor_friction(qd) if self.motor is not None
                                                       else 0.0))[None]
            s = MotionSignals(np.array([context.get_time() + self.session_time_s]), q[None], qd[None],
                              np.zeros((1, self.n)), load)
            for eff in self._general:
                tau = tau + eff.torque(s)[0]
        return tau

    def _calc_actuation(self, context: Context, output: BasicVector) -> None:
        if self.elasticity is not None:
            output.SetFromVector(-self._link_on_state(context))
        else:
            output.SetFromVector(self._u_motor.Eval(context) - self._link_on_state(context))

    def _update_motor(self, context: Context, discrete_state: DiscreteValues) -> None:
        n, motor = self.n, self.motor
        x = context.get_discrete_state(self._state).value()
        tau_s = self._u_net.Eval(context) + self._link_on_state(context)  # the spring torque the plant applied
        tau_m = self._u_motor.Eval(context)
        theta_dot = x[n:] + self.time_step / motor.motor_inertia * (tau_m - motor.friction(x[n:]) - tau_s)
        discrete_state.set_value(self._state, np.concatenate([x[:n] + self.time_step * theta_dot, theta_dot]))

    def set_motor_state(self, context: Context, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> None:
        """Start the elastic drive in equilibrium with link state (q, q̇) carrying torque ``tau``:
        θ = q + τ/K, θ̇ = q̇ (no-op for the rigid drive)."""
        if self.elasticity is not None:
            context.SetDiscreteState(self._state, np.concatenate([q + tau / self.elasticity.stiffness, qd]))


def AddJointDrive(builder: DiagramBuilder, n: int, link_effects: list[JointEffect], motor: Motor | None = None,
                  elasticity: Elasticity | None = None, time_step: float = 1e-3,
                  name: str = "joint_drive", session_time_s: float = 0.0,
                  drive_offset: np.ndarray | None = None, coupling: np.ndarray | None = None,
                  model_plant: MultibodyPlant | None = None) -> JointDrive | FrictionDrive | CoupledDrive:
    """Add the drive to ``builder`` (ports ``motor_torque``, ``link_state`` → ``actuation``; ``session_time_s`` [s]:
    the session clock at context time 0, for time-varying link effects): a :class:`CoupledDrive` when ``coupling``
    puts rotor inertia off the diagonal (``model_plant``: a continuous plant of the arm with the diagonal rotor
    inertia), else a :class:`FrictionDrive` (C++) when :func:`friction_only`, else the Python :class:`JointDrive`."""
    reflected = np.zeros((n, n)) if motor is None else reflected_inertia(motor, coupling)
    if elasticity is None and np.any(reflected != np.diag(np.diag(reflected))):
        if model_plant is None:
            raise ValueError("AddJointDrive: a coupled rotor inertia needs model_plant (the twin's plant with the "
                             "diagonal rotor inertia, continuous)")
        drive = builder.AddSystem(CoupledDrive(n, link_effects, motor, coupling, model_plant, time_step,
                                               session_time_s, drive_offset))
    elif friction_only(link_effects, elasticity):
        drive = builder.AddSystem(FrictionDrive(n, link_effects, motor, session_time_s, drive_offset, coupling))
    else:
        drive = builder.AddSystem(JointDrive(n, link_effects, motor, elasticity, time_step, session_time_s,
                                             drive_offset, coupling))
    drive.set_name(name)
    return drive
