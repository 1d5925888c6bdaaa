"""Helpers for the notebooks (need IPython and ipywidgets, the ``lab``/``test`` extras): an ``interact`` whose errors
fail a headless run, and inline display of a self-contained HTML page (e.g. a Meshcat playback)."""
from __future__ import annotations

import html
from typing import Any, Callable

__all__ = ["interact", "html_iframe"]


def interact(f: Callable[..., Any], **controls: Any):
    """``ipywidgets.interactive(f, **controls)``, displayed. ipywidgets only prints an exception raised by ``f``
    into the widget's output; here the first call (with the controls' defaults, made while the cell runs) re-raises
    it, so a notebook executed headless (``make test``) fails on it. Later calls (the reader moving a control) show
    the traceback in the output as usual. Returns the widget."""
    import ipywidgets
    from IPython.display import display

    errors: list[BaseException] = []

    def guarded(**kwargs: Any) -> Any:
        try:
            return f(**kwargs)
        except Exception as exc:
            errors.append(exc)
            raise

    widget = ipywidgets.interactive(guarded, **controls)
    display(widget)
    if errors:
        raise errors[0]
    return widget


def html_iframe(page: str, height: int = 480):
    """An IPython ``HTML`` object showing the self-contained page ``page`` (e.g.
    :func:`proprio.diagrams.playback.playback_html`'s) inline, in an iframe of ``height`` px; it keeps working in the
    saved notebook (no server behind it)."""
    from IPython.display import HTML

    return HTML(f'<div><iframe srcdoc="{html.escape(page, quote=True)}" style="width:100%;height:{int(height)}px;'
                'border:1px solid #ddd"></iframe></div>')
