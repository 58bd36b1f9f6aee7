"""``python -m companion``: the ``companion`` command line."""

import sys

from companion.cli import main

sys.exit(main())
