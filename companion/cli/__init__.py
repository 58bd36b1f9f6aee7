"""The ``companion`` command line: one module per command family (docs/architecture.md).

The only package of ``companion`` that may import the simulator (``companion_sitl``).
"""

from companion.cli.main import main

__all__ = ["main"]
