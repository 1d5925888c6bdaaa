"""``python -m proprio``: the same command line as the ``proprio`` console script.

``python -m`` puts the working directory first on ``sys.path``; it is taken off again (unless ``-P`` already did)
so that, as with the console script, a ``.py`` file lying next to a config is never importable by accident."""
import os
import sys

if not sys.flags.safe_path and sys.path and os.path.realpath(sys.path[0] or os.curdir) == os.path.realpath(os.getcwd()):
    del sys.path[0]

from proprio.cli import main  # noqa: E402  (after the path is fixed)

sys.exit(main())
