"""Progress bars, drawn only where they can be redrawn: on a terminal or in a notebook. Redirected to a file or a pipe
there is no bar (a bar's carriage-return updates would fill the file with one long line). Every bar of proprio is
made here."""
from __future__ import annotations

import sys
from typing import Any, Iterable

__all__ = ["progress_bar"]


def progress_bar(iterable: Iterable | None = None, *, enabled: bool = True, **kwargs: Any):
    """A ``tqdm`` bar over ``iterable`` (``tqdm``'s keywords), disabled unless ``enabled`` and stderr is a terminal or
    the bar is a notebook widget (:mod:`tqdm.auto`)."""
    from tqdm.auto import tqdm
    from tqdm.autonotebook import tqdm as chosen      # tqdm.std's bar, or in a notebook kernel tqdm.notebook's
    from tqdm.std import tqdm as terminal_bar

    widget = chosen is not terminal_bar
    shown = enabled and (widget or _isatty(kwargs.get("file", sys.stderr)))
    return tqdm(iterable, disable=not shown, **kwargs)


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):        # no isatty, or a closed stream
        return False
