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
    """bondc's cache folder, as :func:`bondc.runtime.cache_dir` gives it (a test keeps the two
    equal): ``$BONDC_CACHE_DIR``, else the user cache directory (platformdirs). Written out here
    because the runtime, which a generated module carries whole, imports numpy: ``bondc check``
    needs the folder but not numpy."""
    given = os.environ.get("BONDC_CACHE_DIR")
    if given:
        return Path(given)
    import platformdirs

    return Path(platformdirs.user_cache_dir("bondc", appauthor=False))


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

    def load(self):
        """The cached ``Derived``, or None (a miss: absent, stale imports or unreadable)."""
        derived = self._read("derived.pickle") if self._current() else None
        if derived is not None:
            self.remember(derived.state_space)
        return derived

    def load_light(self):
        """The cached ``Derived`` with a :class:`LightStateSpace` (no sympy), or None when the entry
        has none yet (it is written after the first full simulation) or is a miss."""
        if not self._current() or not (self.folder / "module.py").is_file():
            return None
        derived = self._read("light.pickle")
        if derived is not None:
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
            values={name: float(value) for name, (_, value) in ss.parameters.items()}, recipes=recipes)
        try:
            data = pickle.dumps(dataclasses.replace(derived, state_space=light), protocol=pickle.HIGHEST_PROTOCOL)
            _atomic_write(self.folder / "light.pickle", data)
        except Exception:       # noqa: BLE001  (a cache must never fail the run)
            return

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
            _atomic_write(path, stamp + marshal.dumps(code))
        except (OSError, ValueError):
            pass
        return code


class LightStateSpace:
    """What a cached ``bondc simulate`` needs of a state space, without sympy.

    The generated module (``module.py``) runs the simulation; this holds the graph, the
    parameters' values, the state names, the diagnostics, and the stored-energy functions as
    recipes (:func:`bondc.analysis.energy.energy_from_recipe`), so that a cached run imports
    neither sympy nor lark. Anything else is read from the full state space, loaded (with
    sympy) on first use.
    """

    def __init__(self, graph, diagnostics, state_names, values, recipes):
        self.graph = graph
        self.diagnostics = diagnostics
        self.state_names = state_names
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

                raise UsageError(Diagnostic("error", "E803", "cannot simulate: the compile cache entry of "
                                                             "this model was removed during the run",
                                            hint="run the command again"))
            self._full = derived.state_space
        return self._full

    def light_energy(self, parameters) -> dict | None:
        """The stored-energy functions for these parameter values, or None when they are not the
        values the recipes were printed with (their numbers are the parameters')."""
        if any(float(parameters.get(name, value)) != value for name, value in self.values.items()):
            return None
        from bondc.analysis.energy import energy_from_recipe

        return {name: energy_from_recipe(kind, state, recipe) for name, (kind, state, recipe) in self.recipes.items()}

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
