"""Algorithms: the learned residual (thesis §4.2, §4.4) — features, datasets, models, training, evaluation — with no Drake
Systems."""
