"""Optional numba compilation of the core's two hot loops, loaded when first called.

With numba installed (the default install), ``njit`` compiles; without it the same Python
functions run uncompiled (about 100x slower, identical results), so the core never *needs*
numba.  ``PIEZOFIN_NO_NUMBA=1`` forces the uncompiled path.

numba is imported by the first call of a compiled function, not at import: it costs about 60 MB
of memory and a second of start-up, and the nodes a fish runs (``thrust_estimator``,
``controller``) never call a compiled loop.
"""

from __future__ import annotations

import functools
import importlib.util
import os
from collections.abc import Callable
from typing import Any

NUMBA = not os.environ.get("PIEZOFIN_NO_NUMBA") and importlib.util.find_spec("numba") is not None


def njit(**options: Any) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """``numba.njit(**options)``, applied when the function is first called (identity without numba)."""

    def decorate(function: Callable[..., Any]) -> Callable[..., Any]:
        if not NUMBA:
            return function
        compiled: Callable[..., Any] | None = None

        @functools.wraps(function)
        def call(*args: Any) -> Any:
            nonlocal compiled
            if compiled is None:
                from numba import njit as numba_njit

                compiled = numba_njit(**options)(function)
            return compiled(*args)

        return call

    return decorate


__all__ = ["NUMBA", "njit"]
