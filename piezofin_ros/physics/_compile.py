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


#: set by :func:`load`: a long computation asked for the compiled steady solutions
_ASKED = False


def compiled_newton() -> bool:
    """Whether the steady amplitude's Newton iterations run compiled: once a long computation asked
    for them (:func:`load`), never otherwise.  Numba loaded for the time-domain loop alone (``fin_sim``)
    does not switch them: a first call compiles for up to a second, which a live node must not spend
    in its loop.  Both paths give the same amplitudes, bit for bit."""
    return NUMBA and _ASKED


def load() -> None:
    """Load numba now and run the steady solutions compiled from here on (:func:`compiled_newton`),
    for a long computation: a diagnosis, the paper's fits."""
    global _ASKED
    if NUMBA:
        import numba  # noqa: F401

        _ASKED = True


__all__ = ["NUMBA", "compiled_newton", "load", "njit"]
