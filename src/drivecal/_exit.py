"""How this process ends, for work that must finish before the interpreter's teardown.

The ``drivecal`` program (``cli.main()`` without arguments) ends with ``os._exit`` once Python's exit
work is done (threads joined, ``atexit`` callbacks run, output flushed): there is no teardown to wait
for, and a thread still busy in a library's C++ code is simply ended with the process. Elsewhere (drivecal
used from Python) the interpreter tears down every module and object, and such a thread must be done
first (``model._preload`` waits for the program it is loading).
"""

from __future__ import annotations

#: True in the ``drivecal`` program: the process ends without the interpreter's teardown.
WITHOUT_TEARDOWN = False
