"""Block-rate Systems: a compiled shift register that gathers a fixed-rate signal into chunks, and Python Systems that
gather the chunks into blocks and apply laws once per block.

The pip wheel of Drake has no C++ headers, so a custom System is Python, and a Python callback at every 1 ms step
costs tens of µs. A law that needs no feedback into the simulated motion (the twin's sensors and logger) therefore
runs at block rate. Measured costs that shape the design (this machine, per 1 ms step of the twin): every System
with a timed event ≈ 0.2 µs (the Simulator asks each for its next event time at every step, due or not); every
extra stop of the Simulator ≈ 12 µs; a ``Selector`` ≈ 5 ns per element; a ``Demultiplexer``/``Multiplexer`` port
≈ 0.3 µs; ``OutputPort.Eval`` of a vector in Python ≈ 10 ns per element (``EvalBasicVector(...).get_value()`` is
a view: 1 µs).

* :class:`BlockRegister` (:func:`AddBlockRegister`) — Drake primitives only, added to the caller's Diagram itself
  (``levels`` = chunks per level, e.g. two levels of 10 → chunks of 100 samples). Level 0 is a shift register of
  ``levels[0]`` samples: a ``ZeroOrderHold`` updated every ``time_step`` at the step's instant, fed by a ``Selector``
  that drops the oldest sample and appends the newest, joining the sample's input ports itself (one compiled
  System, where a ``Demultiplexer`` + ``Multiplexer`` pair would evaluate a port per sample at every step). Level
  k ≥ 1 shifts whole chunks of the level below the same way (a ``Selector``: measured ≈ 1 µs per step cheaper on
  the twin than a ``Demultiplexer`` + ``Multiplexer`` with a port per chunk) once per ``Π levels[:k]`` steps.
  Level 1 fires at the instant of the step after its chunk, together with level 0, whose old state it reads
  (simultaneous updates read the state before the step) — when its period is the step times ``levels[0]`` exactly
  in doubles (10 × 1 ms is; 10 × 0.1 ms is not): then its event times and the steps' are the same doubles and the
  Simulator stops no more often than the plant's step (a stop costs ≈ 12 µs, ≈ 1.2 µs per step at every tenth
  step). Otherwise, and for the levels above, a level fires at a fractional phase of a step (``+ 0.5`` for level 1,
  ``+ 0.1`` per level above the one below), so that no two updates that feed each other share an instant (event
  times ``i·dt + k·P·dt`` and ``(i + kP)·dt`` need not be the same double). Its output ``block`` holds the last
  chunk's samples, oldest first, from the phase :attr:`BlockRegister.phase` of the chunk's last step until the next
  chunk's; ``recent`` is level 0.
* :class:`BlockStage` — one law ``law(inputs, carry) -> (block, carry')`` as a stateless Python System (no events;
  its output depends on its input ports only).
* :class:`BlockClock` — the one Python System with events: once per chunk it copies the register's chunk into its
  discrete state (a chunk at a time: a third register level would copy the whole block element by element every
  chunk), and once per block, right after the block's last chunk, it evaluates the stages' outputs (each law runs
  once, in the order the ports feed each other) and keeps every stage's ``carry`` (the law's state between blocks:
  reversal state, random streams' states, ...) as numeric discrete state. So the chain has three Systems with
  events (two register levels and the clock) however many stages it has, and the stages' inputs change only once
  per chunk.

Every System in the Diagram costs ≈ 0.15 µs per step even without events (the Simulator visits each at every
step), a nested Diagram ≈ 0.4 µs, and each link of the chain of ports that a value changing at every step
invalidates ≈ 0.05 µs: the chain keeps all three small.

Blocks of rows are passed as ``[count, final, rows ...]`` vectors (:func:`unpack_rows`): ``count`` rows of a fixed
width, then what the capacity leaves (not read); ``final`` = 1 on the run's last block.
"""
from __future__ import annotations

import math
import mmap
from dataclasses import dataclass
from fractions import Fraction
from typing import Callable, Sequence

import numpy as np
from pydrake.systems.framework import (
    Context, DiagramBuilder, DiscreteValues, InputPort, LeafSystem, OutputPort,
)
from pydrake.systems.primitives import Selector, SelectorParams, ZeroOrderHold

__all__ = ["BlockRegister", "AddBlockRegister", "BlockStage", "BlockClock", "unpack_rows", "stage_block"]

Law = Callable[[list[np.ndarray], np.ndarray], tuple[np.ndarray, bool, np.ndarray]]


def unpack_rows(v: np.ndarray, width: int) -> tuple[np.ndarray, bool]:
    """The rows ``[count, width]`` and the final flag of a ``[count, final, rows ...]`` vector (module docstring)."""
    count = int(v[0])
    return np.asarray(v[2:2 + count * width]).reshape(count, width), bool(v[1])


def _shift(size: int, newest: Sequence[int]) -> Selector:
    """``[held[chunk:], newest_0, newest_1, ...]``: the held ``size`` values shifted by one chunk (``chunk`` = the
    sum of the ``newest`` input ports' sizes), the newest chunk last."""
    pick = SelectorParams.OutputSelection
    chunk = sum(newest)
    return Selector(SelectorParams(
        inputs=[SelectorParams.InputPortParams(name="held", size=size)]
        + [SelectorParams.InputPortParams(name=f"newest_{k}", size=w) for k, w in enumerate(newest)],
        outputs=[SelectorParams.OutputPortParams(name="shifted", selections=(
            [pick(input_port_index=0, input_offset=i) for i in range(chunk, size)]
            + [pick(input_port_index=1 + k, input_offset=i) for k, w in enumerate(newest) for i in range(w)]))]))


@dataclass
class BlockRegister:
    """What :func:`AddBlockRegister` added: ``levels``, the sample's ``width`` (Σ of the input sizes), ``size`` =
    Π levels samples per chunk, the ``phase`` [steps] past a chunk's last step from which ``block`` holds it, the
    level-0 ``Selector``'s input ports ``samples`` (one per size, joined in order into each sample), and the output
    ports ``block`` [size · width] (the last complete chunk's samples, oldest first: sample i of chunk b is step
    ``b·size + i`` of the run, whose time 0 is step 0) and ``recent`` [levels[0] · width] (level 0: the newest
    samples, up to the step just past)."""
    levels: tuple[int, ...]
    width: int
    size: int
    phase: float
    samples: list[InputPort]
    block: OutputPort
    recent: OutputPort


def AddBlockRegister(builder: DiagramBuilder, widths: Sequence[int], time_step: float,
                     levels: Sequence[int] = (10, 10, 10), name: str = "block_register") -> BlockRegister:
    """Add the compiled shift register (module docstring) gathering samples of the inputs of sizes ``widths``, taken
    every ``time_step`` [s], into chunks of ``Π levels`` samples: Systems ``<name>_level<k>`` (``ZeroOrderHold``)
    and ``<name>_level<k>_shift`` (``Selector``) in ``builder`` itself (a Diagram of its own would cost its
    Context ≈ 0.4 µs at every step)."""
    widths = [int(w) for w in widths]
    levels = tuple(int(k) for k in levels)
    newest, chunk, steps = None, sum(widths), 1    # the newest chunk: its port, size [samples·width], period
    phase, samples, recent = 0.0, [], None
    for k, count in enumerate(levels):
        size = chunk * count
        offset = 0.0
        if k == 1 and Fraction(steps * time_step) == steps * Fraction(time_step):
            phase = 1.0     # at the instant of the step after the chunk, with level 0: reads level 0's old state
        elif k >= 1:
            phase = 0.5 if k == 1 else phase + 0.1
            offset = (steps - 1 + phase) * time_step
        hold = builder.AddNamedSystem(f"{name}_level{k}", ZeroOrderHold(steps * time_step, size, offset))
        shift = builder.AddNamedSystem(f"{name}_level{k}_shift", _shift(size, widths if k == 0 else [chunk]))
        builder.Connect(hold.get_output_port(), shift.get_input_port(0))
        if k == 0:
            samples = [shift.get_input_port(1 + j) for j in range(len(widths))]
            recent = hold.get_output_port()
        else:
            builder.Connect(newest, shift.get_input_port(1))
        builder.Connect(shift.get_output_port(), hold.get_input_port())
        newest, chunk, steps = hold.get_output_port(), size, steps * count
    return BlockRegister(levels, sum(widths), math.prod(levels), phase, samples, newest, recent)


class BlockStage(LeafSystem):
    """One law of a block-rate chain (module docstring), stateless: output port ``out`` = ``[carry', count, final,
    rows ...]`` with ``(rows, final, carry') = law(inputs, carry)``, where ``inputs`` are the input ports ``inputs``
    (name → size) and ``carry`` the input port ``carry``, the law's state before this block (a :class:`BlockClock`
    holds it); ``rows`` are at most ``capacity`` rows of ``width``. The port is evaluated once
    per block, by the clock's update (outputs are cached), so the law runs once per block."""

    def __init__(self, inputs: dict[str, int], carry0: np.ndarray, law: Law, capacity: int, width: int):
        super().__init__()
        self._law = law
        self.carry0 = np.asarray(carry0, dtype=float)
        self.width, self.capacity = int(width), int(capacity)
        self._ports = [self.DeclareVectorInputPort(name, size) for name, size in inputs.items()]
        self._carry = self.DeclareVectorInputPort("carry", self.carry0.size)
        # its inputs only: the Simulator's time and state changes at every step do not reach this port's cache
        self.DeclareVectorOutputPort("out", self.carry0.size + 2 + self.capacity * self.width, self._out,
                                     prerequisites_of_calc={self.all_input_ports_ticket()})

    def _out(self, context: Context, output) -> None:
        # read-only views, valid during this call (Eval would copy element by element: ~10 ns per value)
        inputs = [port.EvalBasicVector(context).get_value() for port in self._ports]
        rows, final, carry = self._law(inputs, self._carry.EvalBasicVector(context).get_value())
        value = output.get_mutable_value()
        c = carry.size
        value[:c] = carry
        value[c], value[c + 1] = rows.shape[0], float(final)
        value[c + 2:c + 2 + rows.size] = rows.ravel()


def stage_block(v: np.ndarray, stage: BlockStage) -> tuple[np.ndarray, bool]:
    """The rows and the final flag of ``stage``'s ``out`` value ``v``."""
    return unpack_rows(v[stage.carry0.size:], stage.width)


class BlockClock(LeafSystem):
    """Gathers the chunks of a :class:`BlockRegister` into blocks and runs a chain of :class:`BlockStage` s once per
    block.

    Input port ``chunk`` [``chunk_size``]: the register's output, a chunk of ``chunk_steps`` steps of ``time_step``
    [s]; ``chunks`` chunks make a block. Once per chunk, at ``phase`` steps past the chunk's last step, an update
    copies the chunk into the discrete state ``held`` (output port ``held`` [chunks·chunk_size]: the block), and with
    a block's last chunk the input port ``after`` [``after_size``] (a vector read with the block, e.g. the register's
    ``recent``) into the state ``after`` (output port ``after``). A second update, 0.05 step later, evaluates the
    stages — which read ``held``, ``after`` and their carries from this System's output ports ``carry_<k>`` (each the
    discrete state of stage k's law, to be connected to the stage's ``carry``) — and stores what every stage's
    ``out`` gives (input ports ``stage_<k>``). So the stages' inputs change only with this System's state, once per
    chunk: a port that changes at every step would have the Simulator notify every stage downstream of it at every
    step. The last stage's rows are the chain's output: the update hands them (a copy) to the publish event right
    after it, which writes them after the earlier ones into a buffer of ``max_rows`` rows (allocated, not touched,
    up front; no copy at the end), :meth:`rows` the rows written so far. They are not discrete state: the Simulator
    copies all of a System's discrete state twice at each of its updates, and a block of rows is ~10⁵ values."""

    def __init__(self, stages: Sequence[BlockStage], chunk_size: int, chunks: int, chunk_steps: int,
                 time_step: float, phase: float, max_rows: int, after_size: int):
        super().__init__()
        self._stages = list(stages)
        self._chunk_size, self._chunks = int(chunk_size), int(chunks)
        self._chunk = self.DeclareVectorInputPort("chunk", chunk_size)
        self._after_in = self.DeclareVectorInputPort("after", after_size)
        self._in = [self.DeclareVectorInputPort(f"stage_{k}", st.get_output_port().size())
                    for k, st in enumerate(self._stages)]
        self._held = self.DeclareDiscreteState(np.zeros(chunks * chunk_size))
        self._after = self.DeclareDiscreteState(np.zeros(after_size))
        self._count = self.DeclareDiscreteState(np.zeros(1))
        self.DeclareStateOutputPort("held", self._held)
        self.DeclareStateOutputPort("after", self._after)
        self._state = [self.DeclareDiscreteState(st.carry0) for st in self._stages]
        for k, index in enumerate(self._state):
            self.DeclareStateOutputPort(f"carry_{k}", index)
        last = self._stages[-1]
        self.DeclarePeriodicDiscreteUpdateEvent(chunk_steps * time_step, (chunk_steps - 1 + phase) * time_step,
                                                self._gather)
        block_steps = chunk_steps * chunks
        self.DeclarePeriodicDiscreteUpdateEvent(block_steps * time_step, (block_steps - 1 + phase + 0.05) * time_step,
                                                self._run_stages)
        self.DeclarePeriodicPublishEvent(block_steps * time_step, (block_steps - 1 + phase + 0.1) * time_step,
                                         self._publish)
        # anonymous mmap, faulted in by 4 KiB pages as rows arrive: numpy's own allocation of a large array asks
        # for transparent huge pages, whose faults cost ~6x more here (measured: 2.7 vs 0.4 ms per block of rows)
        shape = (int(max_rows), last.width)
        self._log = np.frombuffer(mmap.mmap(-1, max(8 * shape[0] * shape[1], 8)), dtype=float)[
            :shape[0] * shape[1]].reshape(shape)
        self._logged = 0
        self._pending = np.zeros((0, last.width))

    def rows(self) -> np.ndarray:
        """The rows ``[M, width]`` of the last stage published so far, in order (a view of the buffer)."""
        return self._log[:self._logged]

    def carry(self, context: Context, k: int) -> np.ndarray:
        """Stage ``k``'s carry in ``context`` (this System's)."""
        return context.get_discrete_state(self._state[k]).get_value().copy()

    def _gather(self, context: Context, discrete_state: DiscreteValues) -> None:
        count = int(context.get_discrete_state(self._count).get_value()[0])
        held = discrete_state.get_mutable_vector(self._held).get_mutable_value()
        held[count * self._chunk_size:(count + 1) * self._chunk_size] = self._chunk.EvalBasicVector(context).get_value()
        if count == self._chunks - 1:
            after = self._after_in.EvalBasicVector(context).get_value()
            discrete_state.get_mutable_vector(self._after).SetFromVector(after)
        discrete_state.get_mutable_vector(self._count).SetAtIndex(0, (count + 1) % self._chunks)

    def _run_stages(self, context: Context, discrete_state: DiscreteValues) -> None:
        for port, index, stage in zip(self._in, self._state, self._stages):
            v = port.EvalBasicVector(context).get_value()
            discrete_state.get_mutable_vector(index).SetFromVector(v[:stage.carry0.size])
        self._pending = unpack_rows(v[self._stages[-1].carry0.size:], self._stages[-1].width)[0].copy()

    def _publish(self, context: Context) -> None:
        rows, self._pending = self._pending, self._pending[:0]
        end = self._logged + rows.shape[0]
        if end > self._log.shape[0]:
            raise RuntimeError(f"block_clock: {end} rows published, more than the {self._log.shape[0]} allocated")
        self._log[self._logged:end] = rows
        self._logged = end
