"""One place for the JIT flags of every Numba kernel.

Every kernel is compiled with the same flags (``FLAGS``): cached on disk, IEEE arithmetic
(no fastmath, so results do not depend on the compiler's reassociation), NumPy's error model
(division by zero gives inf/NaN instead of raising, and no zero-checks in hot loops).
Use ``@kernel``, ``@kernel(parallel=True)``, ``@kernel(inline=True)`` or
``@kernel(parallel=True, nogil=True)``.

``inline=True`` inlines at the Numba IR level (``inline="always"``). That multiplies compile time,
but dropping it (``SOFTSHADOWS_IR_INLINE=0``, kept for measuring) made the rasterizer's and
``irregular``'s frames up to 2x slower (docs/results/cold-start.md), so it stays on. Every kernel
is recorded in ``KERNELS`` (the cold-cache check and the warm-up in :mod:`softshadows._warm`).
"""

from __future__ import annotations

import os

import numpy as np
from numba import njit

FLAGS = dict(cache=True, fastmath=False, error_model="numpy")
IR_INLINE = os.environ.get("SOFTSHADOWS_IR_INLINE", "1") != "0"
KERNELS: list = []  # every dispatcher made by @kernel, in import order


def kernel(fn=None, *, parallel: bool = False, inline: bool = False, nogil: bool = False):
    """``njit`` with the project's flags (see the module docstring)."""
    opts = dict(FLAGS)
    if parallel:
        opts["parallel"] = True
    if inline and IR_INLINE:
        opts["inline"] = "always"
    if nogil:
        opts["nogil"] = True

    def wrap(f):
        d = njit(**opts)(f)
        KERNELS.append(d)
        return d

    if fn is None:
        return wrap
    return wrap(fn)


def frozen(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (no copy). Numba compiles a separate specialisation of a kernel for
    a read-only and a writable array of the same dtype and layout: an input that comes both ways
    (a scene's cached geometry is read-only, a caller's arrays are not) is passed frozen, so that
    the kernel compiles once."""
    v = a.view()
    v.flags.writeable = False
    return v
