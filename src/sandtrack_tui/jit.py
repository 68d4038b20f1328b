"""numba compilation as the project uses it (imported only by modules that compile kernels)."""

from __future__ import annotations

import numba


def jit(func=None, *, nogil: bool = False):
    """Compiled, cached on disk next to the module or in the user's cache; without a writable place
    (a read-only install run by another user) compiled in each process instead. The GIL is kept unless
    `nogil` (kernels over many rows, run on several threads at once): releasing it for microseconds would
    only invite thread switches."""
    if func is None:
        return lambda f: jit(f, nogil=nogil)
    try:
        return numba.njit(cache=True, nogil=nogil)(func)
    except RuntimeError:
        return numba.njit(nogil=nogil)(func)
