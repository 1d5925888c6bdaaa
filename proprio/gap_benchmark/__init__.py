"""The withheld-effect benchmark of the gap diagnosis (DESIGN.md "Gap diagnosis", step 5): data made with an effect
the model lacks, diagnosed by :mod:`proprio.diagnosis` without being told, and scored. A workflow above the
diagnosis: it uses the diagnosis, the diagnosis never imports it (import-linter contract ``diagnosis-not-benchmark``).

Modules:

- :mod:`~proprio.gap_benchmark.cases` — the cases (library, null, two-effect, out-of-library, time-varying);
- :mod:`~proprio.gap_benchmark.recordings` — what every family's data share: :class:`CaseData`, the background
  sensor noise, a case's recordings through the twin;
- :mod:`~proprio.gap_benchmark.case_data` — the library cases' data and model (offline, or through the Drake twin);
- :mod:`~proprio.gap_benchmark.drive` — the drive-torque family (``--drive``);
- :mod:`~proprio.gap_benchmark.confusable` — the confusable-pairs family, before and after the designed experiment
  (``--confusable``);
- :mod:`~proprio.gap_benchmark.run` — running the cases (local or Ray, resumable) and scoring them.
"""
