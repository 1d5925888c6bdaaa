"""The sim-to-real gap diagnosis (DESIGN.md "Gap diagnosis"): where the torque gap lies, which unmodelled effect causes
it and how far it shrinks once that effect is added. The withheld-effect benchmark that checks it is a package above
this one (:mod:`proprio.gap_benchmark`); nothing here imports it.

The route (:mod:`~proprio.diagnosis.route`, :func:`diagnose`), one step each, in this order: condition once →
localise → attribute → verdict → patch → replay → report. The rooms:

- :mod:`~proprio.diagnosis.route` — :func:`diagnose`: the route, and what it returns (:class:`Diagnosis`);
- :mod:`~proprio.diagnosis.data` — the simulation model (:class:`SimModel`); the recordings checked and conditioned
  once (:func:`~proprio.diagnosis.data.condition_recordings`) and prepared for fitting (``GapData``);
- :mod:`~proprio.diagnosis.localisation` — *where*: the gap by joint × motion regime × frequency;
- :mod:`~proprio.diagnosis.candidates` — *which* effects could explain it: the candidates and their one registry
  (``base``, ``rigid_body``, ``drive``, ``registry``);
- :mod:`~proprio.diagnosis.fitting` — fitting candidates to the training residual;
- :mod:`~proprio.diagnosis.selection` — *attribute*: greedy forward selection scored on held-out blocks, and the
  statistics it decides with (``forward``, ``block_test``, ``ambiguity``, ``time_variation``);
- :mod:`~proprio.diagnosis.residual` — the remaining residual's structure and the noise findings;
- :mod:`~proprio.diagnosis.hints` — hints beyond the library: a sparse regression of a structured remaining residual;
- :mod:`~proprio.diagnosis.encoder_floor` — the data's position-noise floor against the model's encoder noise;
- :mod:`~proprio.diagnosis.attribution` — what the selection returns (:class:`Attribution`);
- :mod:`~proprio.diagnosis.patch` — the found effects as a twin patch (``twin_patch.yaml``);
- :mod:`~proprio.diagnosis.replay` — the held-out gap re-measured through the (patched) Drake twin;
- :mod:`~proprio.diagnosis.report` — the verdict, the twin-truth comparison and the report files (``verdict``,
  ``truth``, ``document``);
- :mod:`~proprio.diagnosis.discriminate` — the designed experiment that separates tied effects;
- :mod:`~proprio.diagnosis.resolve` — running it and diagnosing again (``--design-experiment`` / ``--resolve``).
"""
from __future__ import annotations

import importlib
from typing import Any

__all__ = ["DiagnosisError", "SimModel", "Diagnosis", "diagnose", "Attribution", "attribute"]

_HOME = {"DiagnosisError": "data", "SimModel": "data", "Diagnosis": "route", "diagnose": "route",
         "Attribution": "attribution", "attribute": "selection.forward"}


def __getattr__(name: str) -> Any:
    """The public names, imported on first use: a module that needs only one room (the CLI's up-front checks read
    :mod:`~proprio.diagnosis.data`'s limits) does not pay for the whole diagnosis."""
    if name in _HOME:
        value = getattr(importlib.import_module(f"proprio.diagnosis.{_HOME[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'proprio.diagnosis' has no attribute {name!r}")
