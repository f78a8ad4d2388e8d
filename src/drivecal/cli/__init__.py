"""The ``drivecal`` command line: one click group whose commands load on first use.

Each command lives in its own module (``_demo``, ``_fit``, ...; registered by name in
``_common.COMMANDS``) and imports its heavy dependencies when run, so the help and
``--version`` answer without loading JAX.
"""

from ._common import EXIT_BAD_INPUT, cli, main

__all__ = ["EXIT_BAD_INPUT", "cli", "main"]
