"""The candidate explanations of the torque gap the diagnosis tests:

- :mod:`~proprio.diagnosis.candidates.base` — the :class:`~proprio.diagnosis.candidates.base.Candidate` interface,
  the library effects the model lacks, the data path's signal lag and encoder noise, and elasticity;
- :mod:`~proprio.diagnosis.candidates.rigid_body` — rigid-body parameter error and an unmodelled payload;
- :mod:`~proprio.diagnosis.candidates.drive` — the drive terms of a drive-torque arm, and what the model's τ is;
- :mod:`~proprio.diagnosis.candidates.registry` — the one registry: the candidate set a diagnosis tests
  (:func:`~proprio.diagnosis.candidates.registry.candidate_set`).
"""
