"""File output helpers: writing a file so that readers never see half of it.

``atomic_write_text(path, text)`` writes ``text`` to a temporary file in the
same directory, flushes it to disk and renames it over ``path`` with
``os.replace`` (atomic on POSIX and Windows within one file system). An
existing file keeps its permission bits.

>>> import tempfile, pathlib
>>> target = pathlib.Path(tempfile.mkdtemp()) / "m.bg"
>>> atomic_write_text(target, "model M\\nend\\n")
>>> target.read_text()
'model M\\nend\\n'
"""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> None:
    """Replace the contents of ``path`` by ``text`` in one step (see the module docstring)."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
    except FileNotFoundError:
        mode = None
    descriptor, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        # newline="" writes "\n" as it is, on every platform
        with os.fdopen(descriptor, "w", encoding=encoding, newline="") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        if mode is not None:
            os.chmod(temporary, mode)
        else:  # mkstemp creates 0600; give a new file the usual permissions
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(temporary, 0o666 & ~umask)
        os.replace(temporary, path)
    except BaseException:
        try:
            os.unlink(temporary)
        except FileNotFoundError:
            pass
        raise
