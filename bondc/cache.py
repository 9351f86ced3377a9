"""The compile cache: a second run on an unchanged model skips parsing, checking, causality,
the equations, code generation and the C build.

An :class:`Entry` is a folder ``<cache_dir>/models/<key>/`` (``cache_dir`` is
``$BONDC_CACHE_DIR`` or the user cache directory from platformdirs, never the
model's folder). The key is a SHA-256 of

- bondc's own code (every source file of the package and its grammar), so that a
  new or edited bondc never reuses an old result;
- the model file's resolved path and its bytes;
- the ``--model``, ``--experiment`` and ``--set`` values (overrides can change structure).

The entry holds ``derived.pickle`` (the checked graph, causality and state
equations), ``module.py`` once a simulation generated its module, and
``depends.json``: the SHA-256 of every other file the model read (imports).
An entry whose imports changed is a miss. The compiled C library is cached
separately, by the hash of its text (``bondc.runtime.load_native``).

Entries are written to a private temporary file and renamed into place, so
concurrent runs never read half an entry; anything unreadable is a miss, never
an error. ``BONDC_CACHE=0`` or ``--no-cache`` turn the cache off. The cache is
the user's own folder; like any cache of compiled code it trusts its content.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import sys
import tempfile
import weakref
from pathlib import Path

#: Bump when the layout of an entry changes.
_LAYOUT = "1"
_CODE_HASH: list = []
_ENTRIES: dict = {}          # id(state space) -> (weakref to it, Entry)


def enabled() -> bool:
    """Whether the cache is on (``BONDC_CACHE`` is not 0/no/off/false)."""
    return os.environ.get("BONDC_CACHE", "1").strip().lower() not in ("0", "no", "off", "false")


def cache_dir() -> Path:
    from bondc.runtime import cache_dir as runtime_cache_dir

    return Path(runtime_cache_dir())


def code_hash() -> str:
    """SHA-256 of bondc's own source files and grammar (computed once per process)."""
    if not _CODE_HASH:
        package = Path(__file__).resolve().parent
        digest = hashlib.sha256(_LAYOUT.encode())
        files = sorted(p for pattern in ("**/*.py", "**/*.lark") for p in package.glob(pattern))
        grammar = package.parent / "grammar"
        if grammar.is_dir():
            files += sorted(grammar.glob("*.lark"))
        for file in files:
            digest.update(str(file.relative_to(file.parents[1])).encode())
            digest.update(file.read_bytes())
        digest.update(sys.version.encode())
        _CODE_HASH.append(digest.hexdigest())
    return _CODE_HASH[0]


def _file_hash(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def _atomic_write(path: Path, data: bytes) -> None:
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
        os.replace(temporary, path)
    except BaseException:
        try:
            os.unlink(temporary)
        except OSError:
            pass
        raise


class Entry:
    """One model's cache folder (it may not exist yet)."""

    def __init__(self, folder: Path, model_path: Path):
        self.folder = folder
        self.model_path = model_path

    @classmethod
    def for_model(cls, path, model=None, experiment=None, sets=()) -> "Entry | None":
        """The entry of this model file and options, or None when the file cannot be read."""
        path = Path(path)
        try:
            resolved = path.resolve()
            text = resolved.read_bytes() if resolved.is_file() else None
        except OSError:
            return None
        if text is None:
            return None
        key = hashlib.sha256()
        key.update(code_hash().encode())
        key.update(json.dumps([str(resolved), str(path), model, experiment,
                               [item if isinstance(item, str) else repr(item) for item in sets or ()]]).encode())
        key.update(hashlib.sha256(text).digest())
        return cls(cache_dir() / "models" / key.hexdigest()[:40], resolved)

    # -- derived model

    def load(self):
        """The cached ``Derived``, or None (a miss: absent, stale imports or unreadable)."""
        try:
            depends = json.loads((self.folder / "depends.json").read_text(encoding="utf-8"))
            for name, digest in depends.items():
                if _file_hash(Path(name)) != digest:
                    return None
            with open(self.folder / "derived.pickle", "rb") as stream:
                derived = pickle.load(stream)  # noqa: S301  (the user's own cache folder, written by bondc)
        except Exception:       # absent, partial or from an incompatible bondc: a miss
            return None
        self.remember(derived.state_space)
        return derived

    def store(self, derived) -> None:
        """Write the entry; a failure (read-only cache, unpicklable value) only means no cache."""
        depends = {}
        for source in getattr(derived.graph, "sources", {}).values():
            path = getattr(source, "path", None)
            if path is None:
                continue
            resolved = Path(path).resolve()
            if resolved != self.model_path:
                digest = _file_hash(resolved)
                if digest is not None:
                    depends[str(resolved)] = digest
        try:
            data = pickle.dumps(derived, protocol=pickle.HIGHEST_PROTOCOL)
            self.folder.mkdir(parents=True, exist_ok=True)
            _atomic_write(self.folder / "derived.pickle", data)
            _atomic_write(self.folder / "depends.json", json.dumps(depends, indent=1).encode())
        except Exception:       # noqa: BLE001  (a cache must never fail the run)
            return
        self.remember(derived.state_space)

    # -- generated module

    def remember(self, state_space) -> None:
        """Link a state space to this entry, so that :func:`module_source` finds its module."""
        try:
            _ENTRIES[id(state_space)] = (weakref.ref(state_space), self)
        except TypeError:
            pass

    def read_module(self) -> str | None:
        try:
            return (self.folder / "module.py").read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            return None

    def write_module(self, source: str) -> None:
        try:
            _atomic_write(self.folder / "module.py", source.encode("utf-8"))
        except OSError:
            pass


def entry_of(state_space) -> Entry | None:
    """The cache entry a state space was loaded from or stored in, if any."""
    found = _ENTRIES.get(id(state_space))
    if found is None or found[0]() is not state_space:
        return None
    return found[1]
