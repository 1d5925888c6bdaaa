"""Every figure the app writes, and the only place in proprio that imports matplotlib.

Each module is named for what it draws: :mod:`~proprio.plots.recording` (q, τ over time),
:mod:`~proprio.plots.trajectory` (flange path, Fig. 4.9), :mod:`~proprio.plots.gap` (gap map, spectra, before/after),
:mod:`~proprio.plots.estimation` (f̂ against truth), :mod:`~proprio.plots.hysteresis` (Fig. 2.5 loops),
:mod:`~proprio.plots.experiments` (hybrid grid, payload errors). The functions take plain arrays and a path and
write a PNG atomically (:func:`proprio.plots.figure.save_figure`); they compute nothing the figure does not need.

This layer sits just above :mod:`proprio.io` and below every other module: it imports only numpy, matplotlib and
:mod:`proprio.io`, so any stage may call it. matplotlib is imported inside the functions (through
:func:`~proprio.plots.figure.pyplot`): ``import matplotlib.pyplot`` costs about 2 s, which ``proprio --help`` and
the commands that draw nothing should not pay.
"""
