"""Which candidates explain the gap: the greedy forward selection and the statistics it decides with.

- :mod:`~proprio.diagnosis.selection.forward` — :func:`~proprio.diagnosis.selection.forward.attribute`: greedy
  forward selection scored on held-out blocks, the backward check of stand-ins, cross-validation;
- :mod:`~proprio.diagnosis.selection.block_test` — the held-out block test (log-ratio per block, t statistic);
- :mod:`~proprio.diagnosis.selection.ambiguity` — which candidates could take a named effect's place (tied sets);
- :mod:`~proprio.diagnosis.selection.time_variation` — whether the gap depends on when the data were taken.
"""
