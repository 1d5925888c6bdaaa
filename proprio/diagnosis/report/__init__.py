"""What the diagnosis tells the person:

- :mod:`~proprio.diagnosis.report.verdict` — the plain-language verdict;
- :mod:`~proprio.diagnosis.report.truth` — twin data only: what was named and fitted against the twin's truth (the
  report's section and the demo's table; the diagnosis itself never reads the truth);
- :mod:`~proprio.diagnosis.report.document` — ``report.md`` / ``report.html`` / ``diagnosis.json``: tables, figures
  and sections.
"""
