"""The sim-to-real gap diagnosis (DESIGN.md "Gap diagnosis"): where the torque gap lies, which unmodelled effect causes
it and how far it shrinks once that effect is added, checked by a withheld-effect benchmark.

Modules, in the order the diagnosis runs:

- :mod:`~proprio.diagnosis.data` — the simulation model (:class:`SimModel`) and recordings prepared for it;
- :mod:`~proprio.diagnosis.time_variation` — whether the gap depends on when the data were taken;
- :mod:`~proprio.diagnosis.localisation` — *where*: the gap by joint × motion regime × frequency;
- :mod:`~proprio.diagnosis.candidates` — *which*: the candidate effects (and
  :mod:`~proprio.diagnosis.rigid_body_candidates`, :mod:`~proprio.diagnosis.drive_candidates`; the set tested:
  :mod:`~proprio.diagnosis.candidate_set`);
- :mod:`~proprio.diagnosis.fitting` — fitting candidates to the training residual;
- :mod:`~proprio.diagnosis.selection` — greedy forward selection, scored on held-out blocks, and its statistics;
- :mod:`~proprio.diagnosis.hints` — hints beyond the library: a sparse regression of a structured remaining residual;
- :mod:`~proprio.diagnosis.encoder_floor` — the data's position-noise floor against the model's encoder noise;
- :mod:`~proprio.diagnosis.verdict` — the plain-language verdict;
- :mod:`~proprio.diagnosis.truth` — twin data only: what was named and fitted against the twin's truth;
- :mod:`~proprio.diagnosis.patch` — the found effects as a twin patch (``twin_patch.yaml``);
- :mod:`~proprio.diagnosis.replay` — the held-out gap re-measured through the (patched) Drake twin;
- :mod:`~proprio.diagnosis.report` — :func:`diagnose`: all of the above as one call and one report;
- :mod:`~proprio.diagnosis.benchmark_cases` — the withheld-effect benchmark's cases;
- :mod:`~proprio.diagnosis.benchmark_case_data` — their data (offline, or through the Drake twin);
- :mod:`~proprio.diagnosis.benchmark` — running and scoring them.
"""
from proprio.diagnosis.data import DiagnosisError, SimModel
from proprio.diagnosis.report import Diagnosis, diagnose
from proprio.diagnosis.attribution import Attribution
from proprio.diagnosis.selection import attribute

__all__ = ["DiagnosisError", "SimModel", "Diagnosis", "diagnose", "Attribution", "attribute"]
