"""Experiments that run the pipeline end to end: the payload experiment (thesis Table 5.4,
:mod:`~proprio.experiments.payload`) and the hybrid-model training runs and ablation grid (Table 5.3,
:mod:`~proprio.experiments.hybrid`)."""
