"""Sensor models of the twin: the link-side joint torque sensor and the joint position encoder.

Each model is the effect library's laws (:mod:`proprio.effects`), in two forms that call the same code:

* :class:`TorqueSensor` — the batch form over a whole motion ``[N, n]`` (the diagnosis' model
  :meth:`proprio.diagnosis.data.SimModel.predict_parts`, the offline gap benchmark);
* :class:`TorqueSensorSystem` and :class:`EncoderSystem` — Drake Systems of the twin's Diagram
  (``proprio.diagrams.twin``). They take the time steps in blocks (:func:`AddSampleBank`: a C++ shift register keeps
  them, so the Python update runs once per block, not per step — the twin stays ≥ 15× real time): the torque
  sensor keeps the scan state of the reversal-dependent effects (hysteresis, lost motion:
  :meth:`~proprio.effects.Hysteresis.scan`) as discrete state and evaluates the memoryless effects (ripple,
  offset/gain, drift, plugins) by their ``torque`` on the block, the white noise through
  :meth:`~proprio.effects.TorqueNoise.from_normal`; the encoder is :meth:`~proprio.effects.EncoderNoise.reading`.
  Random draws are keyed on (seed, stream, block) (:class:`BlockSystem`). Tests: the System's output equals the
  batch form on the same inputs to 1e-12 N·m.

Torque sensor chain (thesis §2.1): ``τ_meas = (1 + g)·(τ_J + τ_hyst + τ_lost + τ_ripple) + o + o_d(t) + noise``,
i.e. the strain-gauge effects act on the transmitted τ_J, the gain/offset error on everything the gauge sees, a
drifting offset ``o_d`` (``offset_drift``, on the session clock ``MotionSignals.t``) adds to it, and white noise is
added last. Sensor-side plugins (:mod:`proprio.effects.plugins`) act with the strain-gauge effects, after the
library's, on the transmitted τ_J (``s.tau``); in the twin they are evaluated block by block (a sensor-side plugin
is a function of each sample's t, q, q̇, q̈, τ_J, not of the samples before it). Every contribution is returned
separately (the twin's ``tau_<effect>`` truth channels).
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
import scipy.sparse
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import (BasicVector, CacheEntry, Context, DiagramBuilder, LeafSystem, OutputPort,
                                       ValueProducer)
from pydrake.systems.primitives import Multiplexer, SparseMatrixGain, ZeroOrderHold

from proprio.effects import EncoderNoise, JointEffect, OffsetDrift, SensorOffsetGain, TorqueNoise
from proprio.reversals import reversal_scan
from proprio.signals import MotionSignals

__all__ = ["TorqueSensor", "TorqueSensorSystem", "EncoderSystem", "BlockSystem", "AddSampleBank"]

_GAUGE_ORDER = ("hysteresis", "lost_motion", "ripple")
_SENSOR_LIBRARY = ("sensor_offset_gain", "offset_drift", "torque_noise")   # library sensor effects past the gauge


class TorqueSensor:
    """The joint torque sensor: the sensor-side torque effects of a twin, applied in the physical order above."""

    def __init__(self, effects: list[JointEffect]):
        bad = [e.name for e in effects if e.place != "sensor" or isinstance(e, EncoderNoise)]
        if bad:
            raise ValueError(f"TorqueSensor: {bad} are not torque-sensor effects")
        by_name = {e.name: e for e in effects}
        library = set(_GAUGE_ORDER) | set(_SENSOR_LIBRARY)
        # the library's strain-gauge effects in their order, then sensor-side plugins in the config's order
        self.gauge = [by_name[k] for k in _GAUGE_ORDER if k in by_name] + \
            [e for e in effects if e.name not in library]
        self.offset_gain: SensorOffsetGain | None = by_name.get("sensor_offset_gain")
        self.drift: OffsetDrift | None = by_name.get("offset_drift")
        self.noise: TorqueNoise | None = by_name.get("torque_noise")

    @property
    def effects(self) -> list[JointEffect]:
        """All effects in the order they act (gauge, offset/gain, drift, noise)."""
        return self.gauge + [e for e in (self.offset_gain, self.drift, self.noise) if e is not None]

    def measure(self, s: MotionSignals, tau_j: np.ndarray, rng: np.random.Generator | None = None
                ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Measured torque ``[N,n]`` N·m for true link motion ``s`` and true transmitted torque ``tau_j``, and the
        contribution of each effect (keys = effect names). ``rng`` is needed only with ``torque_noise``."""
        s = s.with_tau(tau_j)
        parts: dict[str, np.ndarray] = {}
        seen = tau_j.copy()
        for eff in self.gauge:
            parts[eff.name] = eff.torque(s, rng)
            seen += parts[eff.name]
        if self.offset_gain is not None:
            parts[self.offset_gain.name] = self.offset_gain.torque(s.with_tau(seen), rng)
            seen = seen + parts[self.offset_gain.name]
        if self.drift is not None:
            parts[self.drift.name] = self.drift.torque(s, rng)
            seen = seen + parts[self.drift.name]
        if self.noise is not None:
            parts[self.noise.name] = self.noise.torque(s, rng)
            seen = seen + parts[self.noise.name]
        return seen, parts


def AddSampleBank(builder: DiagramBuilder, ports: list[OutputPort], block_steps: int, time_step: float,
                  name: str = "sample_bank") -> tuple[OutputPort, int]:
    """Add a shift register of C++ systems that keeps the last ``block_steps`` samples of ``ports``: a
    ``ZeroOrderHold`` (period ``time_step``, offset 0: it samples at the discrete plant's own instants, seeing what
    the plant sees) of ``[B·m]`` fed with ``[its own rows 2 … B; the new sample]`` by a ``SparseMatrixGain``. Between
    the time steps ``k`` and ``k + 1`` its output holds the samples of steps ``k − B + 1 … k``, oldest first (each
    ``[m]`` = the ports concatenated). :class:`BlockSystem` s read it once per B steps. Returns ``(output port, m)``."""
    m = sum(port.size() for port in ports)
    size = block_steps * m
    sample = builder.AddSystem(Multiplexer([port.size() for port in ports]))
    sample.set_name(f"{name}_sample")
    for k, port in enumerate(ports):
        builder.Connect(port, sample.get_input_port(k))
    cat = builder.AddSystem(Multiplexer([size, m]))
    shift = builder.AddSystem(SparseMatrixGain(scipy.sparse.eye(size, size + m, k=m, format="csc")))
    hold = builder.AddSystem(ZeroOrderHold(time_step, size))
    hold.set_name(name)
    builder.Connect(hold.get_output_port(), cat.get_input_port(0))
    builder.Connect(sample.get_output_port(), cat.get_input_port(1))
    builder.Connect(cat.get_output_port(), shift.get_input_port())
    builder.Connect(shift.get_output_port(), hold.get_input_port())
    return hold.get_output_port(), m


class BlockSystem(LeafSystem):
    """Base of the measurement chain's Systems: they take the time steps of ``time_step`` [s] from ``start_time`` [s]
    in blocks of ``block_steps`` from an :func:`AddSampleBank`. A block is read half a step after its last step
    (:meth:`block_time`: between the plant's instants, never tied with them): the System's outputs then hold that
    block, computed once into a cache entry from the bank, the System's small discrete state (the carried scan state)
    and the time; a periodic discrete update at the same instants carries the state on. A Diagram's user reads the
    outputs at the block times. Random draws of a block come from a counter-based generator (Philox) keyed on
    (``seed``, ``stream``) at the counter of the block's first step: a function of the seed and the block, no hidden
    state."""

    def __init__(self, block_steps: int, time_step: float, start_time: float, seed: int, stream: int):
        super().__init__()
        self.block_steps, self.time_step, self.start_time = int(block_steps), float(time_step), float(start_time)
        self.seed, self.stream = int(seed), int(stream)

    def block_time(self, j: int) -> float:
        """The instant [s] block ``j`` (steps ``j·B … j·B + B − 1``) is read: half a step after its last step. The
        same floating-point expression as the update event's time (offset + j·period), so advancing a Simulator to
        it stops just before that update."""
        period, offset = self.block_steps * self.time_step, self.start_time + (self.block_steps - 0.5) * self.time_step
        return offset + j * period

    def declare_block(self, calc: Callable[[Context], Any], state: Any = None) -> CacheEntry:
        """Declare the cache entry holding ``calc(context)`` (the block's results; ``[0]`` is the state after the
        block when ``state`` is the index of the System's discrete state group) and, with ``state``, the periodic
        update that carries the state on at the block times."""
        entry = self.DeclareCacheEntry("block", ValueProducer(allocate=lambda: AbstractValue.Make(None),
                                                              calc=lambda context, value: value.set_value(calc(context))))
        if state is not None:
            self.DeclarePeriodicDiscreteUpdateEvent(
                self.block_steps * self.time_step, self.block_time(0),
                lambda context, discrete_state: discrete_state.set_value(state, entry.Eval(context)[0]))
        return entry

    def block(self, context: Context) -> tuple[np.ndarray, np.ndarray]:
        """``(step indices [B], times [B] s)`` of the block read at this context's time."""
        last = int(round((context.get_time() - self.start_time) / self.time_step - 0.5))
        steps = last - self.block_steps + 1 + np.arange(self.block_steps)
        return steps, self.start_time + steps * self.time_step

    def rng(self, steps: np.ndarray) -> np.random.Generator:
        """The generator of the block starting at step ``steps[0]``."""
        return np.random.Generator(np.random.Philox(key=[self.seed, self.stream], counter=[int(steps[0]), 0, 0, 0]))


class TorqueSensorSystem(BlockSystem):
    """The twin's joint torque sensor for ``n`` joints: every sensor-side effect of ``effects`` (not the encoder's),
    block by block (module docstring, :class:`BlockSystem`).

    Input port ``samples`` [B·w]: per time step a row of ``w`` whose columns ``offset … offset + 4n`` (``row = (w,
    offset)``; default ``(4n, 0)``) are ``[a; q; q̇; q̈]`` — ``a`` the transmitted torque τ_J [N·m] or, with
    ``transmission``, what ``transmission(a, t, q, q̇, q̈)`` turns into τ_J (the twin: the plant's net actuation and
    :meth:`proprio.systems.joint_drive.JointDrive.sensed_torque`), link q [rad], q̇ [rad/s], q̈ [rad/s²]. Output
    ports (the block read at this time, :class:`BlockSystem`): ``tau_measured`` [B·n] N·m and ``record``
    [B·(2 + k)·n], per time step ``[τ_meas; τ_J; the contribution of each of the k effects in :attr:`names` order]`` N·m. Discrete state: the
    scan state of the reversal-dependent effects (:meth:`~proprio.effects.Hysteresis.scan`), started at rest at the
    first sample. The effects see the session clock ``t + session_time_s`` [s]; the noise draws ``z`` are standard
    normal (stream 0 of ``seed``).
    """

    def __init__(self, n: int, effects: list[JointEffect], time_step: float = 1e-3, block_steps: int = 1,
                 session_time_s: float = 0.0, start_time: float = 0.0, seed: int = 0,
                 transmission: Callable[..., np.ndarray] | None = None, row: tuple[int, int] | None = None):
        super().__init__(block_steps, time_step, start_time, seed, stream=0)
        sensor = TorqueSensor([e for e in effects if e.place == "sensor" and not isinstance(e, EncoderNoise)])
        self.n, self.sensor = n, sensor
        self.session_time_s, self.transmission = float(session_time_s), transmission
        self.names = [e.name for e in sensor.effects]
        self._stateful = [hasattr(e, "scan") for e in sensor.gauge]
        sizes = [e.state_size * n if st else 0 for e, st in zip(sensor.gauge, self._stateful)]
        self._slices = [slice(int(a), int(a + b)) for a, b in zip(np.cumsum([0] + sizes[:-1]), sizes)]
        self._row = row or (4 * n, 0)                                  # (width of a time step's row, offset)
        self._samples = self.DeclareVectorInputPort("samples", self.block_steps * self._row[0])
        self._state = self.DeclareDiscreteState(sum(sizes) + 1)          # + started flag
        self._block = self.declare_block(self._calc_block, self._state)
        self.DeclareVectorOutputPort("tau_measured", self.block_steps * n,
                                     lambda context, out: out.SetFromVector(self._block.Eval(context)[1]),
                                     prerequisites_of_calc={self._block.ticket()})
        self.DeclareVectorOutputPort("record", self.block_steps * (2 + len(self.names)) * n,
                                     lambda context, out: out.SetFromVector(self._block.Eval(context)[2]),
                                     prerequisites_of_calc={self._block.ticket()})

    def measure_block(self, x: np.ndarray, s: MotionSignals, tau_j: np.ndarray, z: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        """One block: from state ``x`` (empty or started) and samples ``s`` ``[B, n]`` with τ_J and noise draws
        ``z``, return ``(state after, τ_meas [B, n], contributions)``; the same laws, in the same order, as
        :meth:`TorqueSensor.measure`."""
        x = x.copy()
        if x[-1] == 0:                                               # first block: start at rest at sample 0
            for eff, st, sl in zip(self.sensor.gauge, self._stateful, self._slices):
                if st:
                    x[sl] = eff.initial_state(s.q[0], s.qd[0], tau_j[0])
            x[-1] = 1.0
        s = s.with_tau(tau_j)
        sensor, parts, travel = self.sensor, [], {}
        seen = tau_j.copy()
        for eff, st, sl in zip(sensor.gauge, self._stateful, self._slices):
            if st:                     # effects with the same deadband share one reversal scan (same tracker state)
                key = eff.reversal_velocity.tobytes()
                if key not in travel:
                    travel[key] = reversal_scan(x[sl][:5 * self.n], s.q, s.qd, eff.reversal_velocity)
                x[sl], c = eff.scan(x[sl], s.q, s.qd, tau_j, travel[key])
            else:
                c = eff.torque(s)
            parts.append(c)
            seen = seen + c
        if sensor.offset_gain is not None:
            parts.append(sensor.offset_gain.torque(s.with_tau(seen)))
            seen = seen + parts[-1]
        if sensor.drift is not None:
            parts.append(sensor.drift.torque(s))
            seen = seen + parts[-1]
        if sensor.noise is not None:
            parts.append(sensor.noise.from_normal(z))
            seen = seen + parts[-1]
        return x, seen, parts

    def _calc_block(self, context: Context) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n, b = self.n, self.block_steps
        width, first = self._row
        blk = self._samples.Eval(context).reshape(b, width)[:, first:first + 4 * n]
        a, q, qd, qdd = (blk[:, k * n:(k + 1) * n] for k in range(4))
        steps, t = self.block(context)
        tau_j = a if self.transmission is None else self.transmission(a, t, q, qd, qdd)
        z = self.rng(steps).standard_normal((b, n))
        x, seen, parts = self.measure_block(context.get_discrete_state(self._state).value(),
                                            MotionSignals(t + self.session_time_s, q, qd, qdd), tau_j, z)
        return x, seen.ravel(), np.hstack([seen, tau_j, *parts]).ravel()


class EncoderSystem(BlockSystem):
    """The joint position encoder for ``n`` joints: :meth:`~proprio.effects.EncoderNoise.reading` (noise, then
    quantisation; ideal without an ``encoder``) block by block (:class:`BlockSystem`; draws: stream 1 of ``seed``).
    Input port ``samples`` [B·w]: per time step a row of ``w`` whose column ``offset …`` holds the link q [rad]
    (``row = (w, offset)``, default ``(n, 0)``). Output port ``q_measured`` [B·n] rad of the block read at this time
    (no state)."""

    def __init__(self, n: int, encoder: EncoderNoise | None, time_step: float = 1e-3, block_steps: int = 1,
                 start_time: float = 0.0, seed: int = 0, row: tuple[int, int] | None = None):
        super().__init__(block_steps, time_step, start_time, seed, stream=1)
        self.n, self.encoder = n, encoder
        self._row = row or (n, 0)
        self._samples = self.DeclareVectorInputPort("samples", self.block_steps * self._row[0])
        self.DeclareVectorOutputPort("q_measured", self.block_steps * n, self._calc_measured)

    def _calc_measured(self, context: Context, output: BasicVector) -> None:
        width, first = self._row
        q = self._samples.Eval(context).reshape(self.block_steps, width)[:, first:first + self.n]
        if self.encoder is not None:
            steps, _ = self.block(context)
            q = self.encoder.reading(q, self.rng(steps).standard_normal(q.shape))
        output.SetFromVector(q.ravel())
