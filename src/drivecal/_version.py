"""drivecal's version (one place; the package, the result JSON and the CLI read it here)."""

__version__ = "0.2.0"
