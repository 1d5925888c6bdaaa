"""The project's user-error family: an error caused by the user's input (a file, a config, a command-line value),
reported by the command line as one line ``proprio: error: …`` with exit code 2 and no traceback.

:class:`UserError` is a ``ValueError`` so that library callers that catch ``ValueError`` keep working; the library's
own bad-input errors (``RecordingError``, ``TwinConfigError``, ``EffectConfigError``, …) are ``ValueError``
subclasses with a message that names the offending field or file."""
from __future__ import annotations

__all__ = ["UserError"]


class UserError(ValueError):
    """An error caused by the user's input; the message names the offending field, flag or file."""
