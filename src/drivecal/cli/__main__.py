"""``python -m drivecal.cli ARGS``: the same as the ``drivecal`` command."""

import sys

from ._common import main

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
