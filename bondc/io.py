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

import math
import os
import stat
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable
from bondc import codes


_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISLNK, "a symbolic link"), (stat.S_ISFIFO, "a named pipe"),
          (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device"), (stat.S_ISSOCK, "a socket"))


def check_output(path: str | os.PathLike, what: str = "the output", make_folder: bool = False) -> Path:
    """``path`` if bondc may write it, else a UsageError (E003) saying why — before any work.

    bondc replaces only regular files (never a folder, a symbolic link, a named pipe or a
    device), in a folder that exists and can be written (``make_folder``: a writer that
    creates the folder first, like the report's, needs only the first).

    >>> check_output("/nonexistent-folder/out.csv")
    Traceback (most recent call last):
    bondc.errors.UsageError: cannot write the output '/nonexistent-folder/out.csv': the folder '/nonexistent-folder' does not exist
    """
    from bondc.errors import Diagnostic, UsageError

    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")

    def refuse(reason, hint):
        raise UsageError(Diagnostic("error", codes.E003, f"cannot write {what} '{path}': {reason}", hint=hint))

    try:
        info = os.lstat(path)
    except FileNotFoundError:
        info = None
    except OSError as error:
        refuse(error.strerror or str(error), "give another path")
    if info is not None and not stat.S_ISREG(info.st_mode):
        kind = next((name for test, name in _KINDS if test(info.st_mode)), "not a regular file")
        refuse(f"it is {kind}; bondc replaces only regular files",
               "give the path of a new file, or of a regular file to replace")
    if make_folder:
        return path
    if not parent.exists():
        refuse(f"the folder '{parent}' does not exist", f"create it first (mkdir -p '{parent}')")
    if not parent.is_dir():
        refuse(f"'{parent}' is not a folder", "give a path inside a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        refuse(f"the folder '{parent}' is not writable", "write somewhere you may, or change the folder's permissions")
    return path


_WRITES = {"depth": 0, "pending": None}    # atomic writes under way, and a termination they hold back


def hold_termination(exception: BaseException) -> bool:
    """Called by the SIGTERM handler: True if a write is under way (``exception`` is raised when it
    ends, so that a file is never left half-replaced and its content is never lost), else False."""
    if _WRITES["depth"]:
        _WRITES["pending"] = exception
        return True
    return False


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> None:
    """Replace ``path`` by what ``write(handle)`` writes to a binary handle, in one step.

    The temporary file sits in the same directory (``os.replace`` is atomic only
    within one file system); on any failure it is removed and ``path`` is left
    as it was. An existing file keeps its permission bits. A path bondc may not
    write is E003 (:func:`check_output`). When writing fails (a full disk, a
    folder that went away), the content is written to a file in the system's
    temporary folder instead and E004 names it, so that no computed result is lost.
    """
    path = check_output(path)
    _WRITES["depth"] += 1
    try:
        _atomic_write(path, write)
    except OSError as error:
        from bondc.errors import Diagnostic, UsageError

        kept = None
        try:
            descriptor, kept = tempfile.mkstemp(prefix="bondc-", suffix=f"-{path.name}")
            with os.fdopen(descriptor, "wb") as handle:
                write(handle)
        except Exception:       # noqa: BLE001  (nowhere to keep it: say so)
            kept = None
        where = f"; the content is kept in '{kept}'" if kept else ""
        raise UsageError(Diagnostic("error", codes.E004, f"cannot write '{path}': {error.strerror or error}{where}",
                                    hint="free some space or choose another folder, then copy the kept file "
                                         "there" if kept else "free some space or choose another folder")) from None
    finally:
        _WRITES["depth"] -= 1
        pending = _WRITES["pending"] if not _WRITES["depth"] else None
        if pending is not None:
            _WRITES["pending"] = None
            raise pending


def _atomic_write(path: Path, write: Callable[[BinaryIO], None]) -> None:
    directory = path.parent if str(path.parent) else Path(".")
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
    except FileNotFoundError:
        mode = None
    descriptor, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(descriptor, "wb") as handle:
            write(handle)
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


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> None:
    """Replace the contents of ``path`` by ``text`` in one step (see the module docstring).

    The text is written as it is: ``"\\n"`` stays ``"\\n"`` on every platform.
    """
    def write(handle: BinaryIO) -> None:
        if not isinstance(text, str):
            raise TypeError(f"atomic_write_text needs str, not {type(text).__name__}")
        handle.write(text.encode(encoding))

    atomic_write(path, write)


def json_safe(value):
    """A JSON-ready copy of ``value``: JSON has no nan/inf, so they become "nan", "inf", "-inf".

    >>> json_safe({"a": float("nan"), "b": [1.0, float("-inf")]})
    {'a': 'nan', 'b': [1.0, '-inf']}
    """
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, dict):
        return {str(key): json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    if hasattr(value, "item") and getattr(value, "ndim", None) == 0:
        return json_safe(value.item())  # numpy scalars
    if hasattr(value, "tolist"):
        return json_safe(value.tolist())  # numpy arrays
    return value


def read_source(path, name: str | None = None):
    """Read a model file as a :class:`~bondc.source.Source`; an unreadable file is a UsageError (E002).

    >>> read_source("/nonexistent.bg")
    Traceback (most recent call last):
    bondc.errors.UsageError: cannot read '/nonexistent.bg': no such file
    """
    from bondc.errors import Diagnostic, UsageError
    from bondc.source import Source

    path = Path(path)
    name = str(path) if name is None else name
    hint = None
    try:
        return Source(name, path.read_text(encoding="utf-8"), path)
    except FileNotFoundError:
        reason, hint = "no such file", "check the path (relative paths start from the current directory)"
    except IsADirectoryError:
        reason = "it is a directory"
    except UnicodeDecodeError:
        reason, hint = "it is not UTF-8 text", "save the model as UTF-8"
    except OSError as error:
        reason = error.strerror or str(error)
    raise UsageError(Diagnostic("error", codes.E002, f"cannot read '{name}': {reason}", hint=hint))


def cache_dir() -> Path:
    """bondc's cache folder (the compile cache, the parser's tables, the C libraries), as
    :func:`bondc.runtime.cache_dir` gives it (a test keeps the two equal): ``$BONDC_CACHE_DIR``, else the user cache directory (platformdirs). Written out here
    because the runtime, which a generated module carries whole, imports numpy: ``bondc check``
    needs the folder but not numpy."""
    given = os.environ.get("BONDC_CACHE_DIR")
    if given:
        return Path(given)
    import platformdirs

    return Path(platformdirs.user_cache_dir("bondc", appauthor=False))
