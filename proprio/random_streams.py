"""Seeded random streams, one per purpose, and their state as plain numbers.

Every random draw of the twin's measurement chain (each sensor effect's noise, the encoder's noise, the logger's
losses, burst lengths and stamp jitter) comes from its own stream: the child of the config's seed whose spawn key is
the purpose's name (what :meth:`numpy.random.SeedSequence.spawn` does with positions, here with names, so that adding
an effect does not change the others' draws). With one stream per purpose, drawing a motion piece by piece gives
the same numbers as drawing it at once (numpy fills arrays in order; tests), which lets the twin's Diagram apply the
chain block by block.

A stream's state is kept as :data:`STATE_SIZE` float64 numbers (:func:`generator_state`, :func:`generator_from_state`:
PCG64's 128-bit state and increment in 32-bit words, and its buffered 32-bit half), so a Drake System can hold it as
discrete state instead of a Python object that the Simulator would deep-copy at every event.
"""
from __future__ import annotations

import zlib

import numpy as np

__all__ = ["STATE_SIZE", "stream", "generator_state", "generator_from_state"]

STATE_SIZE = 10
_WORD = 1 << 32


def stream(seed: int, purpose: str) -> np.random.Generator:
    """The generator for ``purpose`` (a name, e.g. ``"torque_noise"``) under ``seed``: PCG64 seeded by
    ``SeedSequence(seed, spawn_key=(crc32(purpose),))``."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(seed),
                                                                      spawn_key=(zlib.crc32(purpose.encode()),))))


def _words(x: int) -> list[float]:
    return [float((x >> (32 * k)) & (_WORD - 1)) for k in range(4)]


def _join(words: np.ndarray) -> int:
    return sum(int(w) << (32 * k) for k, w in enumerate(words))


def generator_state(g: np.random.Generator) -> np.ndarray:
    """``[STATE_SIZE]`` numbers that :func:`generator_from_state` turns back into a generator in the same state."""
    st = g.bit_generator.state
    if st["bit_generator"] != "PCG64":
        raise ValueError(f"generator_state: a PCG64 generator is needed, got {st['bit_generator']}")
    return np.array(_words(st["state"]["state"]) + _words(st["state"]["inc"])
                    + [float(st["has_uint32"]), float(st["uinteger"])])


def generator_from_state(v: np.ndarray) -> np.random.Generator:
    """The generator whose state :func:`generator_state` wrote into ``v``."""
    bit = np.random.PCG64(0)           # a cheap seed (no OS entropy), its state replaced at once
    bit.state = {"bit_generator": "PCG64", "state": {"state": _join(v[0:4]), "inc": _join(v[4:8])},
                 "has_uint32": int(v[8]), "uinteger": int(v[9])}
    return np.random.Generator(bit)
