"""scipy's compiled kernels without importing scipy: Brent's root finder and QUADPACK.

``brentq`` and ``quad`` call scipy's compiled routines loaded on their own (importing
``scipy.optimize`` or ``scipy.integrate`` takes half a second); ``_LazyModule`` imports a module
on first use, so that reading a model's data (``bondc check``) imports no scipy.
"""

import functools
import importlib
import os
import sys

import numpy as np


class _LazyModule:
    """A module imported on first use: reading a model's data (``bondc check``) needs no scipy."""

    def __init__(self, name):
        self._name, self._module = name, None

    def __getattr__(self, attribute):
        if self._module is None:
            self._module = importlib.import_module(self._name)
        return getattr(self._module, attribute)


_integrate = _LazyModule("scipy.integrate")
_optimize = _LazyModule("scipy.optimize")


@functools.lru_cache(maxsize=None)
def _scipy_kernel(package, name, probe):
    """scipy's compiled module ``scipy.<package>.<name>``, loaded by itself, or None.

    Importing ``scipy.optimize`` or ``scipy.integrate`` takes 0.3-0.5 s (they import
    scipy.special, scipy.linalg and scipy's array-API layer), about half of a cached
    ``bondc simulate``; the compiled Brent solver and QUADPACK routine they wrap import
    nothing but numpy. The module is loaded from scipy's folder without running its
    package's ``__init__``; ``probe`` (a function of the module) must return True on a
    known problem, so a scipy that moved or changed the routine gives None and the
    caller uses the public function (same routine, slower import)."""
    full = f"scipy.{package}.{name}"
    if full in sys.modules:
        return sys.modules[full]
    try:
        import importlib.machinery
        import importlib.util

        spec = importlib.util.find_spec("scipy")
        for folder in (spec.submodule_search_locations or []) if spec else []:
            for suffix in importlib.machinery.EXTENSION_SUFFIXES:
                path = os.path.join(folder, package, name + suffix)
                if os.path.isfile(path):
                    module_spec = importlib.util.spec_from_file_location(full, path)
                    module = importlib.util.module_from_spec(module_spec)
                    module_spec.loader.exec_module(module)
                    return module if probe(module) else None
    except Exception:           # noqa: BLE001 (any trouble: the public function does the same job)
        return None
    return None


def _zeros_probe(module):
    return module._brentq(lambda x: x - 0.25, 0.0, 1.0, 1e-12, 4 * _EPS, 100, (), False, True) == 0.25


def _quadpack_probe(module):
    value = module._qagse(lambda x: 3.0 * x * x, 0.0, 1.0, (), 0, 1e-14, 1e-12, 50)
    return abs(value[0] - 1.0) < 1e-12 and value[-1] == 0


def brentq(function, a, b, xtol, rtol):
    """``scipy.optimize.brentq(function, a, b, xtol=xtol, rtol=rtol)``: scipy's Brent solver,
    called without importing scipy.optimize (see :func:`_scipy_kernel`). Raises ValueError when
    ``function`` has the same sign at both ends or is nan at a trial point, as scipy's does."""
    kernel = _scipy_kernel("optimize", "_zeros", _zeros_probe)
    if kernel is None:
        return _optimize.brentq(function, a, b, xtol=xtol, rtol=rtol)

    def checked(x):
        value = function(x)
        if np.isnan(value):
            raise ValueError(f"the function value at x={x:.20g} is NaN")
        return value

    return kernel._brentq(checked, a, b, xtol, rtol, 100, (), False, True)


def quad(function, a, b, epsabs, epsrel, limit):
    """The value of ``scipy.integrate.quad(function, a, b, epsabs=..., epsrel=..., limit=...)``
    for finite a and b (QUADPACK's qagse), without importing scipy.integrate. Warnings that
    scipy would give (limit reached, roundoff) are not given: callers judge the value."""
    kernel = _scipy_kernel("integrate", "_quadpack", _quadpack_probe)
    if kernel is None:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", _integrate.IntegrationWarning)
            return float(_integrate.quad(function, a, b, epsabs=epsabs, epsrel=epsrel, limit=limit)[0])
    return float(kernel._qagse(function, a, b, (), 0, epsabs, epsrel, limit)[0])


RUNTIME_VERSION = 1
_EPS = np.finfo(float).eps
