import sys

from proprio.cli import main

sys.exit(main())
