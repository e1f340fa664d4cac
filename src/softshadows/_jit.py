"""One place for the JIT flags of every Numba kernel.

Every kernel is compiled with the same flags (``FLAGS``): cached on disk, IEEE arithmetic
(no fastmath, so results do not depend on the compiler's reassociation), NumPy's error model
(division by zero gives inf/NaN instead of raising, and no zero-checks in hot loops).
Use ``@kernel``, ``@kernel(parallel=True)``, ``@kernel(inline=True)`` (inlined into its
callers at the Numba IR level) or ``@kernel(parallel=True, nogil=True)``.
"""

from __future__ import annotations

from numba import njit

FLAGS = dict(cache=True, fastmath=False, error_model="numpy")


def kernel(fn=None, *, parallel: bool = False, inline: bool = False, nogil: bool = False):
    """``njit`` with the project's flags (see the module docstring)."""
    opts = dict(FLAGS)
    if parallel:
        opts["parallel"] = True
    if inline:
        opts["inline"] = "always"
    if nogil:
        opts["nogil"] = True
    if fn is None:
        return njit(**opts)
    return njit(**opts)(fn)
