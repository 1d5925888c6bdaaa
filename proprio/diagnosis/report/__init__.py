"""What the diagnosis tells the person:

- :mod:`~proprio.diagnosis.report.verdict` — the plain-language verdict: the one sentence and the summary table's
  rows the report opens with, and the details' explanations;
- :mod:`~proprio.diagnosis.report.truth` — twin data only: what was named and fitted against the twin's truth (the
  report's section and the demo's table; the diagnosis itself never reads the truth);
- :mod:`~proprio.diagnosis.report.document` — ``report.md`` / ``report.html`` / ``diagnosis.json``: tables, figures
  and sections (the HTML: the Markdown rendered by ``markdown`` into the Jinja2 template
  ``templates/report.html.j2``).
"""
