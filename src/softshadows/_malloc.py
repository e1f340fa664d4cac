"""Keep large buffers in the process heap between frames (glibc only).

A frame allocates tens of megabytes of short-lived arrays (maps, G-buffers, rasterizer bins).
glibc serves blocks above its mmap threshold with fresh ``mmap`` pages and trims freed heap
memory back to the system, so every frame pays a page fault per 4 KiB page it touches first:
measured on ``bunny`` at 512x512, ~4,000 faults and ~10 ms of a 52 ms ``penumbra-map`` frame
(~140 faults for ``hard``). Raising the mmap and trim thresholds keeps that memory in the heap,
where the next frame reuses it: the same frame then takes ~42 ms with ~5 faults.

:func:`tune_malloc` changes the whole process's allocator, so importing the library never calls
it: the ``softshadows`` command line and the benchmarks call it at start-up (they own the
process), unless the environment sets ``SOFTSHADOWS_TUNE_MALLOC=0``; a program that embeds the
library may call ``softshadows.tune_malloc()`` itself for the same ~20% on page-fault-heavy frames. The cost is that the process keeps up to
``TRIM_THRESHOLD`` bytes of freed memory instead of returning it to the system. On other C
libraries (macOS, musl) it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

#: glibc mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: blocks up to this size come from the heap, not from fresh mmap pages
MMAP_THRESHOLD = 256 * 1024 * 1024
#: freed heap memory kept for reuse before any is returned to the system
TRIM_THRESHOLD = 1024 * 1024 * 1024

_done = None


def tune_malloc() -> bool:
    """Raise glibc's mmap and trim thresholds (once). True if they were set."""
    global _done
    if _done is not None:
        return _done
    _done = False
    if not sys.platform.startswith("linux") or os.environ.get("SOFTSHADOWS_TUNE_MALLOC", "1") == "0":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
    ok = (mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1) and ok
    _done = ok
    return ok
