"""The ``drivecal`` command line: one click group; commands import their heavy dependencies when run."""

from ._commands import EXIT_BAD_INPUT, cli, main

__all__ = ["EXIT_BAD_INPUT", "cli", "main"]
