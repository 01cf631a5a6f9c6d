"""The three LAPACK routines the fit calls on every iteration (dposv, dpocon, dsyevd), scipy's own, loaded
on first use from scipy's compiled LAPACK module alone (~4 ms) rather than through `import scipy.linalg`
(~0.25-0.36 s: scipy's array-API layer touches numpy.testing and numpy.f2py): `accel-calib --help` and a
replay start without it, and every fit gives the same numbers as with scipy.linalg.lapack.

numpy's own LAPACK (numpy.linalg's gufuncs, called without its Python wrappers) was measured as the other
way: a sphere9 fit of 14 poses took 699 us against 449 us with these routines (errstate and NaN checks
around each call), so it is not used. Should scipy's module not be where expected, scipy.linalg.lapack is
imported the ordinary way: slower to start, the same routines.
"""
from __future__ import annotations

import importlib.machinery
import importlib.util
from pathlib import Path
from typing import Any

_routines: Any = None


def _flapack() -> Any:
    """scipy's compiled LAPACK wrappers (the module scipy.linalg.lapack re-exports), imported once."""
    global _routines
    if _routines is None:
        _routines = _load_alone() or _load_through_scipy()
    return _routines


def _load_alone() -> Any:
    try:
        spec = importlib.util.find_spec("scipy")  # finds the package without importing it
        if spec is None or not spec.submodule_search_locations:
            return None
        folder = Path(next(iter(spec.submodule_search_locations))) / "linalg"
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = folder / f"_flapack{suffix}"
            if path.is_file():
                loader = importlib.machinery.ExtensionFileLoader("scipy.linalg._flapack", str(path))
                module_spec = importlib.util.spec_from_file_location("scipy.linalg._flapack", path, loader=loader)
                if module_spec is None:
                    return None
                module = importlib.util.module_from_spec(module_spec)
                loader.exec_module(module)
                return module if all(hasattr(module, name) for name in ("dposv", "dpocon", "dsyevd")) else None
    except (ImportError, OSError, ValueError):
        return None
    return None


def _load_through_scipy() -> Any:
    from scipy.linalg import lapack

    return lapack


def dposv(*args: Any, **kwargs: Any) -> Any:
    """scipy.linalg.lapack.dposv: (Cholesky factor, solution, info)."""
    return _flapack().dposv(*args, **kwargs)


def dpocon(*args: Any, **kwargs: Any) -> Any:
    """scipy.linalg.lapack.dpocon: (reciprocal condition estimate, info)."""
    return _flapack().dpocon(*args, **kwargs)


def dsyevd(*args: Any, **kwargs: Any) -> Any:
    """scipy.linalg.lapack.dsyevd: (eigenvalues, eigenvectors, info)."""
    return _flapack().dsyevd(*args, **kwargs)
