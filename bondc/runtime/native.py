"""Native code: bondc's C and C++ sources (``bondc/native``), compiler discovery (``$CC``, the
system's, zig's from the ``ziglang`` package), the SUNDIALS link, the per-machine build cache, and
:func:`attach_native`, which makes a model evaluate its compiled C functions."""

import atexit
import collections as _collections
import functools
import math
import os
import time as _time_module

import numpy as np

from bondc.runtime.adapter import pattern_arrays


# ------------------------------------------------------------ native code

#: The three C functions of ``NATIVE_SOURCE`` (see ``bondc.codegen.emit._NativeEmitter``).
_NATIVE_FUNCTIONS = ("bondc_rhs", "bondc_jac", "bondc_switches", "bondc_when_conditions", "bondc_when_actions")
#: a model with a nonlinear algebraic loop also has its outputs and variables in C (where C can print them)
_NATIVE_POINT_FUNCTIONS = ("bondc_outputs", "bondc_variables")
#: ... and each of its functions but the Jacobian over many points in one call (``<name>_at``)
_NATIVE_AT_FUNCTIONS = ("bondc_rhs", "bondc_switches") + _NATIVE_POINT_FUNCTIONS
#: Compiler flags: no contraction into fused multiply-adds, so C rounds like numpy.
_NATIVE_FLAGS = ("-fPIC", "-shared", "-ffp-contract=off")
#: Optimisation by the size of each translation unit's text: gcc's -O2 (and -O1) grow much faster
#: than linearly on one function of thousands of statements (measured: the 100-section chain's
#: 73 kB, 1.0 s; the 300-section chain's 186 kB, 5 s; the 1000-section chain's Jacobian, 160 kB of
#: stores into its output, 11 s, against 0.35 s at -O0). Hand-written models are far below the limit
#: (the flagship: 11 kB). A large model's own small units (its switching functions, the CVODE
#: driver) are still -O2: the driver's loops over every state at every step (the finiteness checks,
#: the stored steps) took 10 % of the 1000-section chain's run at -O0.
_NATIVE_OPTIMIZE = ((100_000, "-O2"), (float("inf"), "-O0"))
#: From this size of C text on, each function of the model (and the driver) is compiled as a
#: translation unit of its own, all at once, and the objects are linked: on a 2-core machine the
#: 10000-section chain's build takes 11 s instead of 17 s. A model's C text marks where its units
#: begin (``UNIT_MARK``, written by bondc's code generation); the part before the first is the
#: prelude every unit starts with. The limit is -O2's: a text above it in one unit was all -O0, and the
#: 100-section chain's (56 kB) with the driver (50 kB) ran its right-hand side and the driver's loops
#: unoptimised (the explicit stepper's run 2.4 times as long).
_NATIVE_SPLIT_FROM = _NATIVE_OPTIMIZE[0][0]
UNIT_MARK = "/* ---- bondc: a translation unit of its own ---- */\n"
_NATIVE_LIBRARIES: dict = {}        # digest -> (ffi, lib) loaded in this process
_NATIVE_BY_TEXT: dict = {}          # (id of a model's C text object, SUNDIALS link) -> (it, digest, (ffi, lib))
_NATIVE_NOTES: set = set()          # reasons already printed (each once per process)


def cache_dir() -> str:
    """bondc's cache folder: ``$BONDC_CACHE_DIR``, else the user cache directory (platformdirs)."""
    given = os.environ.get("BONDC_CACHE_DIR")
    if given:
        return given
    try:
        import platformdirs
    except ImportError:         # a standalone module where platformdirs is not installed
        return os.path.join(os.path.expanduser("~"), ".cache", "bondc")
    return platformdirs.user_cache_dir("bondc", appauthor=False)


#: bondc's native sources, by file name: the C and C++ files of the folder ``bondc/native`` (package
#: data). ``driver.c``, bondc's CVODE driver, is built into a model's library where scikit-sundae's
#: SUNDIALS libraries can be linked: it integrates a segment with the model's C functions and
#: watches its switching functions, returning to Python only at a possible crossing, the segment's
#: end, or anything unusual; ``driver.h`` declares what Python calls of it (cffi's cdef reads it),
#: ``sundials.h`` what it calls of SUNDIALS, ``model.h`` the model's functions it calls.
#: ``erk.cpp`` is bondc's explicit stepper (C++, a library of its own, built once per machine and
#: shared by every model): Boost.Odeint's Dormand-Prince 5(4) pair and its continuous extension,
#: whose steps are controlled as scipy's RK45 controls them (its error norm, step factors, first step
#: and smallest step), so the C code and the numpy code (scipy's RK45) take the same steps to
#: rounding; the driver calls it through its table of functions (``erk_api.h``,
#: ``bondc_driver_explicit``) instead of CVODE, for the solver DOPRI5 (and ``auto`` on a model that
#: is not stiff). The integration formulas, the error estimate and the interpolant are odeint's; the
#: file adds the controller's policy and the stop at a segment's end.
#: None: read from the package. A generated module that carries this runtime (``bondc compile
#: --standalone``) sets it after its copy to the files' text (``{name: text}``), so that it builds
#: them where bondc is not installed.
_NATIVE_FILES = None
_NATIVE_READ: dict = {}         # file name -> its text, read from the package once per process


def native_file(name: str) -> str:
    """The text of bondc's native source ``name`` (``driver.c``, ...): the generated module's own copy
    (``_NATIVE_FILES``), else the package's file ``bondc/native/<name>``. Raises OSError (KeyError
    for a module's copy) where it is missing."""
    if _NATIVE_FILES is not None:
        return _NATIVE_FILES[name]
    text = _NATIVE_READ.get(name)
    if text is None:
        folder = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "native")
        with open(os.path.join(folder, name), encoding="utf-8") as stream:
            text = _NATIVE_READ[name] = stream.read()
    return text


def native_build_text(name: str, within=()) -> str:
    """The text of bondc's native source ``name`` as it is compiled: each ``#include "file"`` line of
    it replaced by that file's text (of the same folder, its own includes replaced in turn), so that
    the compiler needs no include folder and the cache key (a hash of the compiled text) covers the
    headers too."""
    parts = []
    for line in native_file(name).splitlines(keepends=True):
        if line.startswith('#include "'):
            included = line.split('"')[1]
            if included in within + (name,):
                raise OSError(f"bondc's native source {name} includes {included} again")
            parts.append(native_build_text(included, within + (name,)))
        else:
            parts.append(line)
    return "".join(parts)


_ERK_FLAGS = ("-O3", "-fPIC", "-shared", "-ffp-contract=off", "-std=c++17")
_ERK_LOADED: dict = {}          # (cache folder, $CXX, $PATH) -> (ffi, lib, table address) or (None, None, why)


#: The compilers bondc builds its native code with, per language: ``$CC`` (``$CXX``) where it names a
#: program, then the system's on PATH, then zig's (the ``ziglang`` package, one of bondc's
#: dependencies: a C and C++ compiler wherever pip installs bondc). Each candidate builds a small
#: shared library once per machine (a compiler without its C library's headers fails there) and the
#: outcome is recorded in ``cache_dir()/native``; the first that builds is the one, and its name and
#: version are part of the cache key of every library it builds.
_SYSTEM_COMPILERS = {"c": ("CC", ("cc", "gcc", "clang")), "c++": ("CXX", ("c++", "g++", "clang++"))}
#: zig's flags on top of bondc's: code for the architecture's baseline processor, as a system
#: compiler makes it (zig's default is this machine's processor), and no UndefinedBehaviorSanitizer
#: (zig's default below -O2: large models' units are compiled at -O0, and a signed overflow would
#: abort the process)
_ZIG_FLAGS = ("-mcpu=baseline", "-fno-sanitize=undefined")
#: (file name, text, flags) of the library each language's candidates build once
_COMPILER_PROBES = {
    "c": ("probe.c", "#include <math.h>\ndouble bondc_probe(double x) { return sin(x); }\n", ("-lm",)),
    "c++": ("probe.cpp", "#include <algorithm>\n#include <vector>\nextern \"C\" double bondc_probe(double x)\n"
            "{ std::vector<double> v{x, 1.0}; return *std::max_element(v.begin(), v.end()); }\n",
            ("-std=c++17",)),
}
_COMPILERS: dict = {}       # (language, $CC or $CXX, $PATH) -> (Compiler or None, why)


#: A compiler bondc builds with: ``command`` (the program and the flags it always gets), ``label``
#: (its version and where it is, as ``stats["compiler"]`` shows it) and ``identity`` (what the cache
#: keys of its builds carry)
Compiler = _collections.namedtuple("Compiler", "command label identity")


def find_compiler(language="c"):
    """``(Compiler, "")`` for ``language`` ("c" or "c++"), or ``(None, why none)``; chosen once per
    process (for the same ``$CC``/``$CXX`` and PATH) from the outcomes recorded for this machine."""
    variable = _SYSTEM_COMPILERS[language][0]
    key = (language, os.environ.get(variable, ""), os.environ.get("PATH", ""))
    known = _COMPILERS.get(key)
    if known is None:
        known = _COMPILERS[key] = _choose_compiler(language)
    return known


def _zig():
    """The zig program the ``ziglang`` package ships, or None."""
    import importlib.util

    try:
        spec = importlib.util.find_spec("ziglang")
    except (ImportError, ValueError):
        return None
    for folder in (spec.submodule_search_locations or []) if spec is not None else []:
        program = os.path.join(folder, "zig.exe" if os.name == "nt" else "zig")
        if os.access(program, os.X_OK):
            return program
    return None


def _choose_compiler(language):
    import shlex
    import shutil

    variable, names = _SYSTEM_COMPILERS[language]
    kind = "C" if language == "c" else "C++"
    given = os.environ.get(variable, "").strip()
    try:
        words = shlex.split(given)
    except ValueError:
        words = []
    candidates = ([(f"${variable}", words)] if given else []) + [(name, [name]) for name in names]
    failures, seen = [], set()
    if given and not (words and shutil.which(words[0])):
        failures.append(f"${variable} ({given}) was not found")
    for origin, words in candidates:
        program = shutil.which(words[0]) if words else None
        if program is None or os.path.realpath(program) in seen:
            continue
        seen.add(os.path.realpath(program))
        command = (program, *words[1:])
        built, text = _probe_compiler(language, command, (*command, "--version"))
        if built:
            where = "; ".join((" ".join(command), *failures))
            return Compiler(command, f"{text} ({where})", f"{os.path.realpath(program)} {text}"), ""
        failures.append(f"{origin} ({program}) failed ({text})")
    zig = _zig()
    if zig is None:
        failures.append("the ziglang package is not installed")
        return None, f"no {kind} compiler works here ({'; '.join(failures)}; set {variable})"
    command = (zig, "cc" if language == "c" else "c++", *_ZIG_FLAGS)
    built, text = _probe_compiler(language, command, (zig, "version"))
    if not built:
        failures.append(f"zig (the ziglang package) failed ({text})")
        return None, f"no {kind} compiler works here ({'; '.join(failures)}; set {variable})"
    why = "; ".join(failures) or f"no {kind} compiler on PATH"
    return Compiler(command, f"zig {command[1]} {text} (the ziglang package: {why})",
                    f"{os.path.realpath(zig)} zig {text} {' '.join(_ZIG_FLAGS)}"), ""


def _probe_compiler(language, command, version):
    """``(True, its version)`` where ``command`` builds the language's small shared library, else
    ``(False, its first complaint)``: found in this machine's record of the program (by its path,
    size and time), else tried and recorded. A failure is tried again after a day (the C library's
    headers may have been installed since)."""
    import hashlib
    import json
    import shutil
    import subprocess
    import tempfile

    try:
        status = os.stat(command[0])
    except OSError as error:
        return False, str(error)
    name, code, flags = _COMPILER_PROBES[language]
    digest = hashlib.sha256(repr((language, command, os.path.realpath(command[0]), status.st_size,
                                  status.st_mtime_ns, code, flags)).encode("utf-8")).hexdigest()[:24]
    folder = os.path.join(cache_dir(), "native")
    record = os.path.join(folder, f"compiler_{digest}.json")
    try:
        with open(record, encoding="utf-8") as stream:
            known = json.load(stream)
        if known["built"] or _time_module.time() - os.path.getmtime(record) < 86400:
            return bool(known["built"]), str(known["text"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    work = None
    try:
        os.makedirs(folder, exist_ok=True)
        work = tempfile.mkdtemp(dir=folder, prefix="build-")
        source = os.path.join(work, name)
        with open(source, "w", encoding="utf-8") as stream:
            stream.write(code)
        done = subprocess.run([*command, "-O2", "-fPIC", "-shared", "-o", os.path.join(work, "probe.so"), source,
                               *flags], capture_output=True, text=True, timeout=900, cwd=work)
        if done.returncode != 0:
            lines = done.stderr.strip().splitlines() or ["no message"]
            built, text = False, next((line for line in lines if "error" in line), lines[0]).strip()
        else:
            told = subprocess.run(version, capture_output=True, text=True, timeout=60)
            built, text = True, ((told.stdout.strip().splitlines() or ["unknown version"])[0]).strip()
    except (OSError, subprocess.SubprocessError) as error:
        return False, f"could not run: {error}"       # not recorded: it may run another time
    finally:
        if work is not None:
            shutil.rmtree(work, ignore_errors=True)
    try:
        fd, temporary = tempfile.mkstemp(dir=folder, prefix="build-", suffix=".json")
        with os.fdopen(fd, "w", encoding="utf-8") as stream:
            json.dump({"built": built, "text": text, "command": list(command)}, stream)
        os.replace(temporary, record)
    except OSError:
        pass
    return built, text


def compiler_label(language="c") -> str:
    """What ``stats["compiler"]`` (``stats["compiler_cxx"]``) says: the compiler :func:`find_compiler`
    chose for ``language``, its version and why (zig's: why no system compiler), or ""."""
    compiler = find_compiler(language)[0]
    return compiler.label if compiler is not None else ""


def native_turned_off() -> bool:
    """Whether ``BONDC_NATIVE`` turns compiled code off (0, no, off, false)."""
    return os.environ.get("BONDC_NATIVE", "1").strip() in ("0", "no", "off", "false")


def load_erk():
    """``(address of the table, "")`` of bondc's explicit stepper library (``bondc/native/erk.cpp``), or
    ``(None, why not)``: native code turned off, the Boost headers (package boost-headers) or a C++
    compiler missing, a failed build. Built once per machine into ``cache_dir()/native`` (in a
    private folder, then renamed into place) and loaded once per process."""
    if native_turned_off():
        return None, "native code is turned off (BONDC_NATIVE=0)"
    key = (cache_dir(), os.environ.get("CXX", ""), os.environ.get("PATH", ""))
    known = _ERK_LOADED.get(key)
    if known is None:
        known = _ERK_LOADED[key] = _build_erk()
    return (known[2], "") if known[0] is not None else (None, known[2])


def _build_erk():
    """(ffi, lib, table address) of the stepper library, built first where the cache lacks it;
    (None, None, why not) where it cannot be had."""
    try:
        import boost_headers
    except ImportError:
        return None, None, "the Boost headers (the package boost-headers) are not installed"
    include = str(boost_headers.get_include())
    ffi, lib, why = _engine_library("erk.cpp", "c++", _ERK_FLAGS, ("-I", include),
                                    getattr(boost_headers, "__version__", ""), "const void *bondc_erk_table(void);",
                                    "bondc's explicit stepper")
    if ffi is None:
        return None, None, why
    return ffi, lib, int(ffi.cast("uintptr_t", lib.bondc_erk_table()))


def _engine_library(name, language, flags, extra, version, cdef, what):
    """(ffi, lib, "") of one of bondc's own native sources (``bondc/native/<name>``) as a library of
    its own, or (None, None, why not): built once per machine into ``cache_dir()/native`` (in a
    private folder, then renamed into place), keyed by its text, flags and compiler."""
    import hashlib

    try:
        import cffi
    except ImportError:
        return None, None, "cffi is not installed"
    compiler, why = find_compiler(language)
    if compiler is None:
        return None, None, why
    try:
        text = native_build_text(name)
    except (OSError, KeyError) as error:
        return None, None, f"{what}'s source is missing ({error})"
    stem, suffix = os.path.splitext(name)
    digest = hashlib.sha256("\n".join((*flags, compiler.identity, version, text)).encode("utf-8")).hexdigest()[:40]
    path = os.path.join(cache_dir(), "native", f"{stem}_{digest}.so")
    if not os.path.exists(path):
        import shutil
        import subprocess
        import tempfile

        work = None
        try:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            work = tempfile.mkdtemp(dir=os.path.dirname(path), prefix="build-")
            source = os.path.join(work, name)
            with open(source, "w", encoding="utf-8") as stream:
                stream.write(text)
            library = os.path.join(work, f"{stem}.so")
            done = subprocess.run([*compiler.command, *flags, *extra, "-o", library, source],
                                  capture_output=True, text=True, timeout=900)
            if done.returncode != 0:
                lines = done.stderr.strip().splitlines() or ["no message"]
                first = next((line for line in lines if "error" in line), lines[0])
                return None, None, f"the {language.upper()} compiler failed on {what} ({first})"
            os.replace(library, path)
        except (OSError, subprocess.SubprocessError) as error:
            return None, None, f"the {language.upper()} compiler could not run ({error})"
        finally:
            if work is not None:
                shutil.rmtree(work, ignore_errors=True)
    ffi = cffi.FFI()
    ffi.cdef(cdef)
    try:
        lib = ffi.dlopen(path)
    except OSError as error:
        return None, None, f"{what} could not be loaded ({error})"
    return ffi, lib, ""


_POLICY_FLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off")
_POLICY_LOADED: dict = {}       # cache folder -> (ffi, lib, "")


def load_policy():
    """``(ffi, lib)`` of bondc's run-loop functions (``bondc/native/policy.c``: Filippov sliding,
    ``filippov.h``, the when clauses, ``events.h``, and the location of ends and dips, ``locate.h``)
    as a library of their own,
    built once per machine and loaded once per process: the one implementation the Python run
    loop calls, whatever computes the model's laws (the CVODE driver and an FMU include the same
    files). Raises :class:`NativeUnavailable` where no C compiler builds it (bondc installs one,
    zig, with its dependencies). ``BONDC_NATIVE=0`` does not turn it off: it is the engine's code,
    not the model's."""
    key = cache_dir()       # (once loaded, whichever compiler built it: the same text; a failure is
    known = _POLICY_LOADED.get(key)     # not kept, the next call tries again)
    if known is None:
        known = _engine_library(
            "policy.c", "c", _POLICY_FLAGS, ("-lm",), "", native_file("filippov.h") + native_file("events.h") + native_file("locate.h"),
            "bondc's run-loop functions")
        if known[0] is None:
            raise NativeUnavailable(known[2])
        _POLICY_LOADED[key] = known
    return known[0], known[1]


class NativeUnavailable(RuntimeError):
    """bondc's own C code (the engine's, not a model's) cannot be built or loaded here."""


_SUNDIALS_PARTS = ("core", "cvode", "nvecserial", "sunmatrixdense", "sunmatrixband", "sunlinsoldense",
                   "sunlinsolband")


@functools.lru_cache(maxsize=None)
def _sundials_link():
    """``(C index type, library paths)`` of the SUNDIALS 7 that scikit-sundae ships (Linux wheels),
    or None: then the driver is not built and the model's C functions run under scikit-sundae.
    Looked up once per process."""
    import glob
    import importlib.util

    try:
        spec = importlib.util.find_spec("sksundae")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin:
        return None
    package = os.path.dirname(spec.origin)
    try:
        with open(os.path.join(package, "py_config.pxi"), encoding="utf-8") as stream:
            config = dict(line.replace('"', "").split(" = ", 1) for line in stream.read().splitlines()
                          if " = " in line)
    except (OSError, ValueError):
        return None
    index = {"int": "int", "int32_t": "int", "long": "long", "int64_t": "long long",
             "long int": "long", "long long": "long long"}.get(config.get("SUNDIALS_INT_TYPE", "").strip())
    if not config.get("SUNDIALS_VERSION", "").startswith("7.") or index is None \
            or config.get("SUNDIALS_FLOAT_TYPE", "").strip() != "double":
        return None
    folder = os.path.join(os.path.dirname(package), "scikit_sundae.libs")
    libraries = []
    for part in _SUNDIALS_PARTS:
        found = sorted(glob.glob(os.path.join(folder, f"libsundials_{part}-*.so*")))
        if not found:
            return None
        libraries.append(found[0])
    return index, tuple(libraries)


def load_native(source, driver=True):
    """``(ffi, lib)`` for the C text ``source``, or ``(None, why not)``.

    The shared library is built once per distinct text and compiler (:func:`find_compiler`:
    ``$CC``, else ``cc``/``gcc``/``clang``, else zig's from the ziglang package) into
    ``cache_dir()/native`` (built in a private folder, then renamed into place, so concurrent
    runs never see half a file)
    and loaded with cffi. ``BONDC_NATIVE=0`` turns native code off. With ``driver`` and
    scikit-sundae's SUNDIALS libraries at hand, bondc's CVODE driver is built in too
    (``hasattr(lib, "bondc_driver_new")``); if that build fails, the model alone is built.
    A large model's functions are compiled as separate units at once (``_NATIVE_SPLIT_FROM``),
    and :func:`start_native` may have started that build already: it is then waited for.
    """
    if native_turned_off():
        return None, "native code is turned off (BONDC_NATIVE=0)"
    # a model's text object seen before in this process (every run of a loaded model): its
    # library without joining and hashing the text again (2 ms for a 1000-section chain)
    key = (id(source), _sundials_link() if driver else None)
    known = _NATIVE_BY_TEXT.get(key)
    if known is not None and known[0] is source and _NATIVE_LIBRARIES.get(known[1]) is known[2]:
        return known[2]
    given = source
    if isinstance(source, (tuple, list)):
        source = "".join(source)
    if not source:
        return None, "the model has no native code"
    why = ""
    for text, libraries in _native_variants(source, driver):
        ffi, lib = _build_native(text, libraries)
        if ffi is not None:
            digest = next((d for d, loaded in _NATIVE_LIBRARIES.items() if loaded[1] is lib), None)
            if digest is not None:
                _NATIVE_BY_TEXT[key] = (given, digest, _NATIVE_LIBRARIES[digest])
            return ffi, lib
        why = why or lib
    return None, why


def _native_variants(source, driver):
    """[(C text, libraries)] to try in order: with bondc's CVODE driver where SUNDIALS can be
    linked, then the model alone."""
    link = _sundials_link() if driver else None
    variants = []
    if link is not None:
        try:        # SUNDIALS' index type, then the driver with its headers (bondc/native/driver.c)
            text = f"#define BONDC_INDEX_TYPE {link[0]}\n" + native_build_text("driver.c")
        except (OSError, KeyError):     # not there (a damaged installation): the model alone
            text = None
        if text is not None:
            variants.append((source + "\n" + UNIT_MARK + text, link[1]))
    variants.append((source, ()))
    return variants


def _native_plan(source, libraries, compiler):
    """(compiler flags, translation units, digest, library path) of a C text built by ``compiler``
    (a :class:`Compiler`)."""
    import hashlib

    def level(text):
        return next(flag for limit, flag in _NATIVE_OPTIMIZE if len(text) < limit)

    flags = (level(source), *_NATIVE_FLAGS)
    texts = _native_units(source)
    # several units: each optimised by its own size; one: by the whole text's
    units = [(text, level(text) if len(texts) > 1 else flags[0]) for text in texts]
    levels = " ".join(level for _, level in units)
    digest = hashlib.sha256("\n".join((*flags, compiler.identity, *libraries, f"units {len(units)} {levels}",
                                       source)).encode("utf-8")).hexdigest()[:40]
    return flags, units, digest, os.path.join(cache_dir(), "native", f"model_{digest}.so")


def _link_flags(libraries):
    return [*libraries, f"-Wl,-rpath,{os.path.dirname(os.path.realpath(libraries[0]))}"] if libraries else []


def _build_native(source, libraries):
    try:
        import cffi
    except ImportError:
        return None, "cffi is not installed"
    compiler, why = find_compiler("c")
    if compiler is None:
        return None, why
    flags, units, digest, path = _native_plan(source, libraries, compiler)
    if digest in _NATIVE_LIBRARIES:
        return _NATIVE_LIBRARIES[digest]
    build = _NATIVE_PENDING.pop(digest, None)        # started ahead by start_native
    if build is not None and build.owner != os.getpid():
        build = None        # a forked process's copy of its parent's build: the parent finishes it
    if not os.path.exists(path):
        import subprocess

        try:
            if build is None:
                os.makedirs(os.path.dirname(path), exist_ok=True)
                build = _NativeBuild(compiler, flags, units, os.path.dirname(path), _link_flags(libraries))
            failure = build.finish()
            if failure:
                return None, f"the C compiler failed ({failure})"
            os.replace(build.library, path)
        except (OSError, subprocess.SubprocessError) as error:
            return None, f"the C compiler could not run ({error})"
        finally:
            if build is not None:
                build.discard()
    else:
        if build is not None:
            build.discard()
        try:        # used now: the compile cache's size cap evicts the least recently used first
            os.utime(path)
        except OSError:
            pass
    ffi = cffi.FFI()
    ffi.cdef("".join(f"void {name}(double t, const double *x, const double *p, const double *m, double *out);\n"
                     for name in _NATIVE_FUNCTIONS + _NATIVE_POINT_FUNCTIONS)
             + "".join(f"void {name}_at(int count, const double *t, const double *x, const double *p, "
                       "const double *m, double *out);\n" for name in _NATIVE_AT_FUNCTIONS)
             + (native_file("driver.h") if libraries else ""))
    try:
        lib = ffi.dlopen(path)
    except OSError as error:
        return None, f"the compiled model could not be loaded ({error})"
    _NATIVE_LIBRARIES[digest] = (ffi, lib)
    return ffi, lib


def start_native(source, driver=True) -> None:
    """Start building, in the background, the library ``load_native(source, driver)`` will load,
    when it is a large model's (compiled as several units) and not built yet: its compilers then
    run while the caller goes on (Python compiling the generated module), and ``load_native``
    waits for them. Does nothing otherwise, or where anything is missing (it is only a head start)."""
    if native_turned_off() or not source:
        return
    if isinstance(source, (tuple, list)):
        source = "".join(source)
    text, libraries = _native_variants(source, driver)[0]
    try:
        compiler = find_compiler("c")[0]
        if compiler is None:
            return
        flags, units, digest, path = _native_plan(text, libraries, compiler)
        if (len(units) == 1 or digest in _NATIVE_LIBRARIES or digest in _NATIVE_PENDING
                or os.path.exists(path)):
            return
        os.makedirs(os.path.dirname(path), exist_ok=True)
        _NATIVE_PENDING[digest] = _NativeBuild(compiler, flags, units, os.path.dirname(path),
                                               _link_flags(libraries))
    except Exception:       # noqa: BLE001  (load_native builds it, and says why not)
        return


def native_text(module_source: str) -> str:
    """The C text of a generated module (its ``NATIVE_SOURCE`` literal), read without running it."""
    import ast as python_ast

    marker = "\nNATIVE_SOURCE = "
    start = module_source.rfind(marker)
    end = module_source.find("\nNATIVE_UNAVAILABLE = ", start)
    if start < 0 or end < 0:
        return ""
    try:
        value = python_ast.literal_eval(module_source[start + len(marker):end])
    except (ValueError, SyntaxError):
        return ""
    return "".join(value) if isinstance(value, tuple) else str(value)


class _NativeBuild:
    """A shared library being compiled: every translation unit's compiler started at once (``-c``
    for several, then a link in :meth:`finish`), in a private folder of the native cache."""

    def __init__(self, compiler, flags, units, directory, link):
        import subprocess
        import tempfile

        self.owner = os.getpid()        # only this process waits for the compilers it started
        self.work = tempfile.mkdtemp(dir=directory, prefix="build-")
        self.library = os.path.join(self.work, "model.so")
        self.compiler, self.flags, self.link = compiler, flags, link
        files = []
        for k, (text, _) in enumerate(units):
            files.append(os.path.join(self.work, f"unit{k}.c"))
            with open(files[-1], "w", encoding="utf-8") as stream:
                stream.write(text)
        if len(files) == 1:
            self.objects = None
            commands = [[*compiler.command, *flags, "-o", self.library, files[0], *link, "-lm"]]
        else:
            self.objects = [name[:-2] + ".o" for name in files]
            compile_flags = [flag for flag in flags[1:] if flag != "-shared"]
            commands = [[*compiler.command, level, *compile_flags, "-c", "-o", obj, name]
                        for (_, level), name, obj in zip(units, files, self.objects)]
        self.runs = [subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                     for command in commands]

    def finish(self) -> str:
        """Wait for the compilers (and link): "" or the compiler's first line of complaint."""
        import subprocess

        def first_line(stderr):
            return (stderr.strip().splitlines() or ["no message"])[0]

        failure = ""
        for run in self.runs:
            _, stderr = run.communicate(timeout=900)
            if run.returncode != 0 and not failure:
                failure = first_line(stderr)
        if failure or self.objects is None:
            return failure
        done = subprocess.run([*self.compiler.command, *self.flags, "-o", self.library, *self.objects, *self.link,
                               "-lm"],
                              capture_output=True, text=True, timeout=900)
        return first_line(done.stderr) if done.returncode != 0 else ""

    def discard(self) -> None:
        """Stop any compiler still running and remove the private folder."""
        import shutil

        for run in self.runs:
            if run.poll() is None:
                run.kill()
                run.wait()
        shutil.rmtree(self.work, ignore_errors=True)


_NATIVE_PENDING: dict = {}          # digest -> _NativeBuild started by start_native


def _discard_pending() -> None:
    while _NATIVE_PENDING:
        build = _NATIVE_PENDING.popitem()[1]
        if build.owner == os.getpid():
            build.discard()


atexit.register(_discard_pending)


def _native_units(source):
    """The C text as the translation units to compile: one, or (from ``_NATIVE_SPLIT_FROM`` on,
    where the text is marked) the prelude followed by each marked part, with the prototypes of the
    model's functions (the driver calls them)."""
    if len(source) < _NATIVE_SPLIT_FROM or UNIT_MARK not in source:
        return [source.replace(UNIT_MARK, "")]
    prelude, *parts = source.split(UNIT_MARK)
    prototypes = "".join(f"void {name}(double t, const double *x, const double *p, const double *m, double *out);\n"
                         for name in _NATIVE_FUNCTIONS)
    return [prelude + prototypes + part for part in parts]


def attach_native(model, native=None):
    """Make ``model`` (a :class:`_Model`) evaluate its right-hand side, Jacobian and switching
    functions (and, with an algebraic loop, its outputs and variables) with its compiled C code;
    returns ``(True, "")`` or ``(False, why not)``.

    ``native`` False keeps the numpy code; None (the default) uses C where it can. Calls the
    C code cannot serve (arrays of times, the mode reader that records which modes a law reads)
    go to the numpy functions, which compute the same values.
    """
    if native is False:
        return False, "numpy code requested"
    source = getattr(model, "NATIVE_SOURCE", "")
    if not source:
        return False, getattr(model, "NATIVE_UNAVAILABLE", "") or "the model has no native code"
    ffi, lib = load_native(source)
    if ffi is None:
        return False, lib
    n, count = len(model.STATE_NAMES), len(model.SWITCHES)
    rows, cols = pattern_arrays(model.JACOBIAN_PATTERN)
    buffer, empty, ndarray, contiguous = ffi.from_buffer, np.empty, np.ndarray, np.ascontiguousarray
    doubles = ffi.typeof("double[]")        # resolved once: these wrappers run thousands of times a run
    c_rhs, c_jac, c_switches = lib.bondc_rhs, lib.bondc_jac, lib.bondc_switches
    numpy_rhs, numpy_jac, numpy_switches = model.rhs, model.jac, model.switches
    held = {}       # "p"/"m" -> (the array given, its C buffer): both are the same for many calls

    def pointer(key, value):
        last = held.get(key)
        if last is not None and last[0] is value:
            return last[1]
        made = buffer(doubles, contiguous(value, dtype=float))
        held[key] = (value, made)
        return made

    def arrays(t, x, p, m):
        """The C arguments, or None for a call the C code cannot serve."""
        if not isinstance(t, float) or type(x) is not ndarray or x.ndim != 1:
            return None
        if count and type(m) is not ndarray:
            return None
        return (float(t), buffer(doubles, contiguous(x, dtype=float)), pointer("p", p),
                pointer("m", m) if count else ffi.NULL)

    # a nonlinear algebraic loop is solved in C by Newton's method; where that fails (its unknowns
    # nan), the numpy module solves it as without C (MINPACK's hybr), so that C never makes a
    # point fail that numpy would have solved
    loops = not getattr(model, "VECTORIZED", True)

    def vector(c_function, numpy_function, size, checked):
        """``c_function`` writing ``size`` values; ``numpy_function`` for a call C cannot serve, or
        (``checked``) where C gives a value that is not finite."""
        def evaluate(t, x, p, m):
            arguments = arrays(t, x, p, m)
            if arguments is None:
                return numpy_function(t, x, p, m)
            out = empty(size)
            if size:
                c_function(*arguments, buffer(doubles, out))
                if checked and not math.isfinite(out.sum()):
                    return numpy_function(t, x, p, m)
            return out
        return evaluate

    def jac(t, x, p, m):
        arguments = arrays(t, x, p, m)
        if arguments is None:
            return numpy_jac(t, x, p, m)
        matrix = np.zeros((n, n))
        if rows.size:
            entries = empty(rows.size)      # in JACOBIAN_PATTERN order
            c_jac(*arguments, buffer(doubles, entries))
            if loops and not math.isfinite(entries.sum()):
                return numpy_jac(t, x, p, m)
            matrix[rows, cols] = entries
        return matrix

    def at_points(c_function, numpy_function, size):
        """``c_function`` (a ``<name>_at``) over the columns of ``x`` in one call: values by
        columns, each exactly the point's call; numpy's where C's is not finite."""
        def evaluate(t, x, p, m):
            t = np.ascontiguousarray(t, dtype=float)
            rows = np.ascontiguousarray(np.asarray(x, dtype=float).T)      # a point's states in a row
            out = empty((t.size, size))
            if size and t.size:
                c_function(t.size, buffer(doubles, t), buffer(doubles, rows), pointer("p", p),
                           pointer("m", m) if count else ffi.NULL, buffer(doubles, out))
                for j in np.flatnonzero(~np.isfinite(out).all(axis=1)):
                    out[j] = numpy_function(float(t[j]), rows[j].copy(), p, m)
            return out.T
        return evaluate

    model.rhs, model.jac = vector(c_rhs, numpy_rhs, n, loops), jac
    model.switches = vector(c_switches, numpy_switches, count, loops)
    # the engine's C functions (runtime.policy) call the library's own where its values are taken
    # as they come (no algebraic loop, whose points numpy solves again where C's are not finite)
    model.native_functions = None if loops else (ffi, lib)
    try:
        when_native = bool(model.WHEN_LABELS) and lib.bondc_when_native() == 1
    except AttributeError:      # a library built before C had the when clauses
        when_native = False
    if when_native:
        # the when clauses' statements from C too: the pieces integrated ahead run them in C, and
        # the run takes those pieces only where its own values are theirs to the bit (numpy's
        # where C's are not finite)
        offsets = np.ascontiguousarray(np.concatenate(([0], np.cumsum([len(targets) for targets in
                                                                        model.WHEN_TARGETS]))), dtype=np.intc)
        c_actions, numpy_actions = lib.bondc_when_actions, model.WHEN_ACTIONS

        def clause(k):
            def action(t, x, p, m):
                arguments = arrays(t, x, p, m)
                if arguments is None:
                    return numpy_actions[k](t, x, p, m)
                out = empty(max(int(offsets[-1]), 1))
                c_actions(*arguments, buffer(doubles, out))
                values = out[offsets[k]:offsets[k + 1]]
                if not math.isfinite(values.sum()):
                    return numpy_actions[k](t, x, p, m)
                return tuple(values)
            return action
        model.WHEN_ACTIONS = tuple(clause(k) for k in range(len(numpy_actions)))
        model.when_offsets = offsets
    if loops:
        # a model with a loop is evaluated point by point: its outputs and variables from C too,
        # where the library has them (C could not print them otherwise); where the library has
        # them, each function also over many points at once (its attribute ``at_points``)
        numpy_functions = {"rhs": numpy_rhs, "switches": numpy_switches}
        for name, size in (("rhs", n), ("switches", count), ("outputs", len(model.OUTPUT_NAMES)),
                           ("variables", len(model.VARIABLE_NAMES))):
            if name not in numpy_functions:
                if not hasattr(lib, f"bondc_{name}"):
                    continue
                numpy_functions[name] = getattr(model, name)
                setattr(model, name, vector(getattr(lib, f"bondc_{name}"), numpy_functions[name], size, True))
            if hasattr(lib, f"bondc_{name}_at"):
                getattr(model, name).at_points = at_points(getattr(lib, f"bondc_{name}_at"), numpy_functions[name],
                                                           size)
    if hasattr(lib, "bondc_driver_new"):
        model.native_library = (ffi, lib)
    return True, ""
