"""The compile cache: a second run on an unchanged model skips parsing, checking, causality,
the equations, code generation and the C build.

An :class:`Entry` is a folder ``<cache_dir>/models/<key>/`` (``cache_dir`` is
``$BONDC_CACHE_DIR`` or the user cache directory from platformdirs, never the
model's folder). The key is a SHA-256 of

- bondc's own code (every source file of the package, its grammar and its C and C++
  sources), so that a new or edited bondc never reuses an old result;
- the model file's resolved path and its bytes;
- the ``--model``, ``--experiment`` and ``--set`` values (overrides can change structure).

The entry holds ``derived.pickle`` (the checked graph, causality and state
equations), ``module.py`` once a simulation generated its module,
``light.pickle`` once ``bondc simulate`` ran it (the graph, the parameter values
and the stored-energy functions as printed recipes: a :class:`LightStateSpace`,
so that the next ``bondc simulate`` imports neither sympy nor lark), and
``depends.json``: the SHA-256 of every other file the model read (imports), and
``module.<python tag>.code``: the module compiled by this Python (as a ``.pyc``).
``bondc check`` keeps what its equations stage found (the states kept, E605 and the other
diagnostics of that stage) in ``<cache_dir>/check/<key>.pickle``, keyed by bondc's code and the
text of every file the model read (:func:`check_key`): checking an unchanged file again needs
no sympy.
An entry whose imports changed is a miss. The compiled C library is cached
separately, by the hash of its text (``bondc.runtime.load_native``).

The compile cache keeps at most ``BONDC_CACHE_MAX_MB`` megabytes (default 1000: 1 GB; 0: no cap)
of compiled models and their C libraries: a running total of what was stored
(``models/.size.json``) says when to measure both folders and evict the least recently used
entries (a hit marks its entry used, loading a C library marks it). :func:`info` and
:func:`clear` are ``bondc cache info`` and ``bondc cache clear``.

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
import re
import sys
import tempfile
import weakref
from pathlib import Path
from typing import TYPE_CHECKING

from bondc.io import cache_dir  # noqa: F401  (bondc's cache folder: bondc.cache.cache_dir as before)
from bondc import codes

if TYPE_CHECKING:
    from bondc.pipeline import Derived

#: Bump when the layout of an entry changes.
_LAYOUT = "1"
_CODE_HASH: list = []
_ENTRIES: dict = {}          # id(state space) -> (weakref to it, Entry)


def enabled() -> bool:
    """Whether the cache is on (``BONDC_CACHE`` is not 0/no/off/false)."""
    return os.environ.get("BONDC_CACHE", "1").strip().lower() not in ("0", "no", "off", "false")


def code_hash() -> str:
    """SHA-256 of bondc's own source files, grammar, component library (``std:`` models are
    read from the package, not from a file the cache could check) and C and C++ sources (a
    generated module carries them) (computed once per process)."""
    if not _CODE_HASH:
        package = Path(__file__).resolve().parent
        digest = hashlib.sha256(_LAYOUT.encode())
        files = sorted(p for pattern in ("**/*.py", "**/*.lark", "std/*.bg", "native/*.c", "native/*.h", "native/*.cpp")
                       for p in package.glob(pattern))
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


def check_key(sources, model=None, sets=()) -> str:
    """The key of ``bondc check``'s equations-stage result: bondc's code, the name and text of
    every file the model read (imports too), the ``--model`` and ``--set`` values."""
    return _files_key(code_hash(), [(name, sources[name].text) for name in sorted(sources)], model, sets)


def _files_key(prefix: str, texts, model, sets) -> str:
    """The hash of ``prefix``, the ``--model`` and ``--set`` values and each (name, text)."""
    digest = hashlib.sha256(prefix.encode())
    digest.update(json.dumps([model, [item if isinstance(item, str) else repr(item) for item in sets or ()]]).encode())
    for name, text in texts:
        digest.update(hashlib.sha256(name.encode("utf-8", "surrogatepass")).digest())
        digest.update(hashlib.sha256(text.encode("utf-8", "surrogatepass")).digest())
    return digest.hexdigest()[:40]


def value_spans(graph) -> dict:
    """Source name -> the (start, end) offsets of every parameter value written as a plain number
    (``param M = 31.7 [kg]``: the ``31.7``; a minus sign included)."""
    from bondc import ast

    spans: dict = {}
    for parameter in getattr(graph, "parameters", {}).values():
        expr = parameter.expr
        number = expr.operand if isinstance(expr, ast.Unary) and expr.op == "-" else expr
        span = getattr(expr, "span", None)
        if isinstance(number, ast.Num) and span is not None and span.end > span.start:
            spans.setdefault(span.file, set()).add((span.start, span.end, span.line))
    return spans


def check_key_of_structure(sources, graph, model=None, sets=()) -> tuple[str, frozenset]:
    """(key, lines): like :func:`check_key`, with each parameter value written as a plain number
    left out of the files' texts (:func:`value_spans`), and the lines ((file, line)) of those
    numbers. An equations stage that no parameter value decided (``values_consulted`` False)
    gives the same states and diagnostics for any values, so a check after an edit of values
    only reuses it; its diagnostics must not lie on those lines (their columns may move)."""
    texts, lines = masked_texts(sources, graph)
    return _files_key("values\0" + code_hash(), texts, model, sets), lines


def masked_texts(sources, graph) -> tuple[tuple, frozenset]:
    """(((source name, text with each parameter value written as a number replaced by a NUL), ...)
    in name order, the (source name, line) of each such number)."""
    spans = value_spans(graph)
    texts, lines = [], set()
    for name in sorted(sources):
        text = sources[name].text
        parts, last = [], 0
        for start, end, line in sorted(spans.get(name, ())):
            parts += [text[last:start], "\0"]
            last = end
            lines.add((name, line))
        parts.append(text[last:])
        texts.append((name, "".join(parts)))
    return tuple(texts), frozenset(lines)


def load_check(key: str):
    """What :func:`store_check` kept under ``key``, or None (absent, unreadable, cache off)."""
    if not enabled():
        return None
    try:
        return pickle.loads((cache_dir() / "check" / f"{key}.pickle").read_bytes())
    except Exception:       # noqa: BLE001  (absent or partial: a miss)
        return None


def store_check(key: str, value) -> None:
    """Keep ``check``'s equations-stage result (the states kept, its diagnostics) for the next
    check of the same files: that one then imports no sympy. A failure only means no cache."""
    if not enabled():
        return
    try:
        folder = cache_dir() / "check"
        folder.mkdir(parents=True, exist_ok=True)
        _atomic_write(folder / f"{key}.pickle", pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
    except Exception:       # noqa: BLE001  (a cache must never fail the run)
        return


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

    def _current(self) -> bool:
        """Whether the files the model imports are unchanged (False when unreadable)."""
        try:
            depends = json.loads((self.folder / "depends.json").read_text(encoding="utf-8"))
        except Exception:       # absent or partial: a miss
            return False
        return all(_file_hash(Path(name)) == digest for name, digest in depends.items())

    def _read(self, name: str):
        """The object pickled in ``name``, or None (absent, partial or from an incompatible bondc)."""
        try:
            with open(self.folder / name, "rb") as stream:
                return pickle.load(stream)  # noqa: S301  (the user's own cache folder, written by bondc)
        except Exception:       # a miss
            return None

    def load(self) -> Derived | None:
        """The cached ``Derived``, or None (a miss: absent, stale imports or unreadable)."""
        derived = self._read("derived.pickle") if self._current() else None
        if derived is not None:
            _touch(self.folder)
            self.remember(derived.state_space)
        return derived

    def load_light(self) -> Derived | None:
        """The cached ``Derived`` with a :class:`LightStateSpace` (no sympy), or None when the entry
        has none yet (it is written after the first full simulation) or is a miss."""
        if not self._current() or not (self.folder / "module.py").is_file():
            return None
        derived = self._read("light.pickle")
        if derived is not None:
            _touch(self.folder)
            derived.state_space.entry = self
            self.remember(derived.state_space)
        return derived

    def store_light(self, derived, recipes: dict) -> None:
        """Write the light form of ``derived`` (see :class:`LightStateSpace`); a failure only means
        that the next run reads the full entry."""
        import dataclasses

        ss = derived.state_space
        light = LightStateSpace(
            graph=ss.graph, diagnostics=tuple(ss.diagnostics), state_names=tuple(ss.state_names),
            values={name: float(value) for name, (_, value) in ss.parameters.items()}, recipes=recipes,
            eliminated_names=tuple(ss.eliminated_names))
        try:
            data = pickle.dumps(dataclasses.replace(derived, state_space=light), protocol=pickle.HIGHEST_PROTOCOL)
            _atomic_write(self.folder / "light.pickle", data)
        except Exception:       # noqa: BLE001  (a cache must never fail the run)
            return
        _grown(len(data))

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
        # what was made from an earlier derivation in this folder (its imports changed since): the
        # generated module carries that one's parameter values and laws
        for stale in ("light.pickle", "module.py", *(path.name for path in self.folder.glob("module.*.code"))):
            try:
                (self.folder / stale).unlink()
            except FileNotFoundError:
                pass
            except OSError:         # cannot remove it: no cache rather than a stale one
                return
        try:
            data = pickle.dumps(derived, protocol=pickle.HIGHEST_PROTOCOL)
            self.folder.mkdir(parents=True, exist_ok=True)
            _atomic_write(self.folder / "derived.pickle", data)
            listed = json.dumps(depends, indent=1).encode()
            _atomic_write(self.folder / "depends.json", listed)
        except Exception:       # noqa: BLE001  (a cache must never fail the run)
            return
        _grown(len(data) + len(listed))
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
            data = source.encode("utf-8")
            _atomic_write(self.folder / "module.py", data)
        except (OSError, UnicodeEncodeError):
            return
        _grown(len(data))

    def module_code(self, source: str, filename: str):
        """``compile(source, filename, "exec")``, kept beside the module as Python keeps a ``.pyc``:
        ``module.<cache tag>.code`` holds this Python's magic number, the SHA-256 of the text and
        file name, and the marshalled code. A cached ``bondc simulate`` then skips compiling the
        module (0.05 s for the flagship). Anything that does not match is compiled again."""
        import importlib.util
        import marshal

        tag = sys.implementation.cache_tag or "python"
        path = self.folder / f"module.{tag}.code"
        stamp = importlib.util.MAGIC_NUMBER + hashlib.sha256(
            "\0".join((filename, source)).encode("utf-8", "surrogatepass")).digest()
        try:
            data = path.read_bytes()
            if data[:len(stamp)] == stamp:
                return marshal.loads(data[len(stamp):])
        except Exception:       # noqa: BLE001  (absent, partial or unreadable: compile)
            pass
        code = compile(source, filename, "exec")
        try:
            data = stamp + marshal.dumps(code)
            _atomic_write(path, data)
        except (OSError, ValueError):
            return code
        _grown(len(data))
        return code


class LightStateSpace:
    """What a cached ``bondc simulate`` needs of a state space, without sympy.

    The generated module (``module.py``) runs the simulation; this holds the graph, the
    parameters' values, the state names, the diagnostics, and the stored-energy functions as
    recipes (:func:`bondc.analysis.energy.energy_from_recipe`), so that a cached run imports
    neither sympy nor lark. Anything else is read from the full state space, loaded (with
    sympy) on first use.
    """

    def __init__(self, graph, diagnostics, state_names, values, recipes, eliminated_names=()):
        self.graph = graph
        self.diagnostics = diagnostics
        self.state_names = state_names
        self.eliminated_names = eliminated_names      # the dependent states (derivative causality)
        self.values = values                        # parameter name -> SI value
        self.recipes = recipes                      # element -> (kind, state name, recipe)
        self.bound_base = None
        self.entry = None                           # set when read from the cache
        self._full = None

    @property
    def parameters(self) -> dict:
        """name -> (None, value): the names and values (the sympy symbols are in the full one)."""
        return {name: (None, value) for name, value in self.values.items()}

    def full(self):
        """The full state space of the same entry (imports sympy)."""
        if self._full is None:
            derived = self.entry.load() if self.entry is not None else None
            if derived is None:
                from bondc.errors import Diagnostic, UsageError

                raise UsageError(Diagnostic("error", codes.E803, "cannot simulate: the compile cache entry of "
                                                             "this model was removed during the run",
                                            hint="run the command again"))
            self._full = derived.state_space
        return self._full

    def light_recipes(self, parameters) -> dict | None:
        """The stored-energy recipes (name -> (kind, state, recipe): what
        :func:`bondc.analysis.energy.energy_from_recipe` makes functions of) for these parameter
        values, or None when they are not the values the recipes were printed with (their numbers
        are the parameters')."""
        if any(float(parameters.get(name, value)) != value for name, value in self.values.items()):
            return None
        return dict(self.recipes)

    def __getattr__(self, name):
        # (only for names this object lacks: while unpickling, before its own attributes are set,
        # those and special names must not reach full())
        if name.startswith("__") or name in ("_full", "entry"):
            raise AttributeError(name)
        return getattr(self.full(), name)


def entry_of(state_space) -> Entry | None:
    """The cache entry a state space was loaded from or stored in, if any."""
    found = _ENTRIES.get(id(state_space))
    if found is None or found[0]() is not state_space:
        return None
    return found[1]


# ------------------------------------------------------------------ size cap and management
#
# ``bondc cache info`` and ``bondc cache clear`` see only what bondc writes: the subfolders below,
# by name, and in each only the entries whose names bondc gives them (``_OWN``). A
# ``BONDC_CACHE_DIR`` that points at a folder holding other files (a home folder, a project) keeps
# them: nothing else is listed, counted or removed, and links are never followed.

#: The caches, in the order ``bondc cache info`` lists them: (name, subfolder, what it holds).
CACHES = (("compile", "models", "derived models, generated modules (the compile cache)"),
          ("check", "check", "what bondc check's equations stage found"),
          ("native", "native", "native libraries (models' C code, the explicit stepper) and compiler probes"),
          ("parser", "parser", "the parser's tables"))

_HEX = "[0-9a-f]{40}"
#: subfolder -> the names of the entries bondc writes there (the temporary files of an interrupted
#: write included)
_OWN = {"models": rf"{_HEX}|\.size\.json|\.tmp-.*",
        "check": rf"{_HEX}\.pickle|\.tmp-.*",
        "native": r"(model|erk)_[0-9a-f]+\.so|compiler_[0-9a-f]+\.json|build-.*|\.tmp-.*",
        "parser": r"lalr-[0-9a-f]+\.lark(\.tmp.*)?|\.tmp-.*"}

#: The compile cache's default cap, in MB (``BONDC_CACHE_MAX_MB`` changes it; 0: no cap).
DEFAULT_MAX_MB = 1000.0
_SIZE_FILE = ".size.json"


def max_bytes() -> int | None:
    """The compile cache's cap in bytes from ``BONDC_CACHE_MAX_MB`` (default :data:`DEFAULT_MAX_MB`),
    None for no cap (0). Raises ValueError for a value that is not a number of megabytes >= 0."""
    import math

    given = os.environ.get("BONDC_CACHE_MAX_MB", "").strip()
    if not given:
        return int(DEFAULT_MAX_MB * 1e6)
    try:
        value = float(given)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"BONDC_CACHE_MAX_MB must be a number of megabytes (0 for no cap), not {given!r}")
    return None if value == 0 else int(value * 1e6)


def _own(subfolder: str, name: str) -> bool:
    import re

    return re.fullmatch(_OWN[subfolder], name) is not None


def _size(path: str) -> int:
    """Bytes of a file, or of every file under a folder (links not followed, not counted)."""
    try:
        status = os.lstat(path)
    except OSError:
        return 0
    import stat

    if stat.S_ISLNK(status.st_mode):
        return 0
    if not stat.S_ISDIR(status.st_mode):
        return status.st_size
    total = 0
    try:
        with os.scandir(path) as items:
            for item in items:
                total += _size(item.path)
    except OSError:
        pass
    return total


def _entries(subfolder: str) -> list[os.DirEntry]:
    """bondc's own entries of one subfolder of the cache (none when it is absent or a link)."""
    folder = cache_dir() / subfolder
    if folder.is_symlink() or not folder.is_dir():
        return []
    try:
        with os.scandir(folder) as items:
            return [item for item in items if _own(subfolder, item.name)]
    except OSError:
        return []


def info() -> dict:
    """What ``bondc cache info`` shows: the folder, whether the cache is on, the compile cache's
    cap, and per cache its folder, entries (files or entry folders; temporary files not counted)
    and bytes."""
    try:
        cap = max_bytes()
    except ValueError:
        cap = int(DEFAULT_MAX_MB * 1e6)
    caches = []
    for name, subfolder, what in CACHES:
        entries = _entries(subfolder)
        counted = [entry for entry in entries if not entry.name.startswith((".tmp-", "build-", ".size"))]
        caches.append({"name": name, "folder": str(cache_dir() / subfolder), "what": what,
                       "entries": len(counted), "bytes": sum(_size(entry.path) for entry in entries)})
    return {"folder": str(cache_dir()), "enabled": enabled(), "max_bytes": cap, "caches": caches,
            "bytes": sum(cache["bytes"] for cache in caches)}


def clear() -> dict:
    """Remove every entry bondc wrote in its caches (``bondc cache clear``): only the entries of
    :data:`CACHES`' subfolders whose names bondc gives (anything else in the folder stays), and the
    subfolders themselves when that leaves them empty. Returns {cache name: (entries, bytes) removed}
    and "kept": the paths of other files found in bondc's subfolders (left as they are)."""
    import shutil

    removed: dict = {}
    for name, subfolder, _ in CACHES:
        count = size = 0
        for entry in _entries(subfolder):
            bytes_ = _size(entry.path)
            try:
                if entry.is_dir(follow_symlinks=False):
                    shutil.rmtree(entry.path)
                else:
                    os.unlink(entry.path)
            except FileNotFoundError:
                continue
            except OSError:
                shutil.rmtree(entry.path, ignore_errors=True)
                if os.path.lexists(entry.path):
                    continue
            count += not entry.name.startswith((".tmp-", "build-", ".size"))
            size += bytes_
        try:
            (cache_dir() / subfolder).rmdir()       # only when empty: other files keep it
        except OSError:
            pass
        removed[name] = (count, size)
    return removed


def _touch(folder: Path) -> None:
    """Mark an entry used now (the cap evicts the least recently used)."""
    try:
        os.utime(folder)
    except OSError:
        pass


def _grown(added: int) -> None:
    """Count ``added`` bytes into the compile cache's running total (``models/.size.json``) and,
    when the total passes the cap, measure the folder and evict the least recently used entries
    (their folders' modification times) until it fits. The folder is measured only then, or when
    the total is absent: a store costs a small read and write otherwise. Never fails a run."""
    try:
        cap = max_bytes()
    except ValueError:
        cap = int(DEFAULT_MAX_MB * 1e6)
    if cap is None:
        return
    models = cache_dir() / "models"
    record = models / _SIZE_FILE
    try:
        total = int(json.loads(record.read_text(encoding="utf-8"))["bytes"]) + added
    except Exception:       # noqa: BLE001  (absent or partial: measure)
        total = None
    try:
        if total is None or total > cap:
            total = _trim(cap)
        _atomic_write(record, json.dumps({"bytes": total}).encode())
    except Exception:       # noqa: BLE001  (a cache must never fail the run)
        return


#: The native libraries of models the size cap counts and evicts (bondc's explicit stepper, built
#: once per machine, and the compiler probes are kept).
_MODEL_LIBRARY = re.compile(r"model_[0-9a-f]+\.so")


def _trim(cap: int) -> int:
    """Evict the compile cache's least recently used entries until it holds at most ``cap`` bytes
    (never the most recently used one); returns the bytes left. The entries are the compiled
    models (``models/``) and their C libraries (``native/model_*.so``, marked used when loaded)."""
    import shutil

    entries = []
    for entry in _entries("models"):
        if entry.name.startswith(".") or not entry.is_dir(follow_symlinks=False):
            continue
        try:
            used = entry.stat(follow_symlinks=False).st_mtime_ns
        except OSError:
            continue
        entries.append((used, entry.path, _size(entry.path)))
    for entry in _entries("native"):
        if not _MODEL_LIBRARY.fullmatch(entry.name) or not entry.is_file(follow_symlinks=False):
            continue
        try:
            stat = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        entries.append((stat.st_mtime_ns, entry.path, stat.st_size))
    entries.sort()
    total = sum(size for _, _, size in entries)
    for _, path, size in entries[:-1]:          # oldest first; the newest stays
        if total <= cap:
            break
        if os.path.isdir(path):
            shutil.rmtree(path, ignore_errors=True)
        else:
            try:
                os.remove(path)
            except OSError:
                pass
        if not os.path.lexists(path):
            total -= size
    return total
