"""Optional numba compilation of the core's two hot loops.

With numba installed (the default install), ``njit`` compiles; without it the same Python
functions run uncompiled (about 100x slower, identical results), so the core never *needs*
numba.  ``PIEZOFIN_NO_NUMBA=1`` forces the uncompiled path.
"""

from __future__ import annotations

import os
from typing import Any

NUMBA = False
if not os.environ.get("PIEZOFIN_NO_NUMBA"):
    try:
        from numba import njit

        NUMBA = True
    except ImportError:  # pragma: no cover - exercised only where numba is missing
        pass

if not NUMBA:

    def njit(*args: Any, **kwargs: Any) -> Any:  # type: ignore[no-redef]
        """Identity decorator standing in for ``numba.njit``."""
        return lambda f: f


__all__ = ["NUMBA", "njit"]
