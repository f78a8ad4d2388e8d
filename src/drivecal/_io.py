"""Writing results: JSON and figures, each file written whole or not at all."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator

from .errors import DrivecalError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    A crash or an exception leaves no partial file behind, and an existing
    file is replaced in one step.
    """
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp makes the file private; give it the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_json(path: str | os.PathLike, payload: Any) -> None:
    """Write ``payload`` as indented JSON, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(payload, indent=2, allow_nan=False) + "\n")


#: Resolution of the PNG files the commands write (dots per inch).
FILE_DPI = 110


def save_figure(fig, path: str | os.PathLike, dpi: int = FILE_DPI) -> None:
    """Save a matplotlib figure as PNG, atomically, and close it."""
    from ._figures import png_bytes

    write_bytes(path, png_bytes(fig, dpi))


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` (a PNG, say) to ``path``, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def check_output_path(path: str | os.PathLike, option: str, *, directory: bool = False,
                      example: str | None = None) -> Path:
    """Refuse an output path that cannot be written, before any work starts; write nothing.

    The one rule of every command's output:

    - an output *file* must not be an existing directory, and its parent must
      be an existing, writable directory (it is not created);
    - an output *directory* (``directory=True``) is either an existing,
      writable directory, or a new one whose parent is an existing, writable
      directory (it is created when the outputs are written).

    Raises:
        DrivecalError: one sentence naming ``option``, the path and the fix.
    """
    out = Path(path)
    what = "directory" if directory else "file"
    shown = f"{option} {out}"
    if str(path) == "":
        raise DrivecalError(f"{option}: the path is empty; give a {what} path"
                            + (f" such as {example}." if example else "."))
    if directory and out.exists():
        if not out.is_dir():
            raise DrivecalError(f"{shown}: this is an existing file, not a directory; give a directory path.")
        if not os.access(out, os.W_OK | os.X_OK):
            raise DrivecalError(f"{shown}: no permission to write in this directory; choose a writable one.")
        return out
    if not directory and out.is_dir():
        raise DrivecalError(f"{shown}: this is a directory, not a file; give a file path"
                            + (f" such as {example}." if example else " inside it."))
    parent = out.parent
    if not parent.exists():
        raise DrivecalError(f"{shown}: the directory {parent} does not exist; create it first "
                            f"(mkdir -p {parent}) or choose another path.")
    if not parent.is_dir():
        raise DrivecalError(f"{shown}: {parent} is a file, not a directory; choose another path.")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise DrivecalError(f"{shown}: no permission to write in {parent}; choose a writable directory.")
    if not directory and out.exists() and not out.is_file():
        raise DrivecalError(f"{shown}: this is not a regular file; choose another path.")
    return out


def prepare_output_dir(path: str | os.PathLike, option: str = "--out") -> Path:
    """Create the output directory (:func:`check_output_path`'s rule: its parent must exist)."""
    out = check_output_path(path, option, directory=True)
    try:
        out.mkdir(exist_ok=True)
    except OSError as exc:
        raise DrivecalError(f"{option} {out}: cannot create the directory ({exc.strerror}); "
                            "choose another path.") from None
    return out
