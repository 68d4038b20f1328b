"""numba compilation as the project uses it (imported only by modules that compile kernels)."""

from __future__ import annotations

import numba


def jit(func):
    """Compiled, cached on disk next to the module or in the user's cache; without a writable place
    (a read-only install run by another user) compiled in each process instead. The GIL is kept:
    releasing it for microseconds would only invite thread switches."""
    try:
        return numba.njit(cache=True)(func)
    except RuntimeError:
        return numba.njit(func)
