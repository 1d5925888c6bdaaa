"""Algorithms: identification of the rigid-body backbone (thesis §3.3, §4.1) — Newton–Euler regressor, base parameters,
excitation design, least squares / SDP — with no Drake Systems."""
