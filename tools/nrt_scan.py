"""List the kernels whose compiled code holds Numba reference-counting calls (``NRT_incref`` /
``NRT_decref``, atomic operations), after a small render of every method on ``bunny`` with both
lights compiled into an empty JIT cache (inspection needs kernels compiled in this process).

    NUMBA_CACHE_DIR=$(mktemp -d) PYTHONPATH=src python tools/nrt_scan.py

A helper that takes arrays and runs in an innermost loop, or a serial work function called from a
parallel kernel's body, can say ``@kernel(..., nrt=False)`` (it must not allocate); see
``softshadows/_jit.py``. The count is static (calls in the function's own code, the Python
wrapper left out), not how often they run.
"""

from __future__ import annotations

import re

from softshadows import api
from softshadows._jit import KERNELS
from softshadows.scene import builtin

METHODS = (
    "hard",
    "pcss",
    "penumbra-map",
    "soft-shadow-map",
    "occlusion-textures",
    "irregular",
    "layered-attenuation",
    "coherent-raytrace",
    "ground-truth",
)


def main() -> None:
    for light in ("rect", "sphere"):
        scene = builtin.build("bunny", light)
        for m in METHODS:
            if m == "coherent-raytrace" and light == "sphere":
                continue
            api.render(scene, m, 48, 32, **({"samples": 4} if m == "ground-truth" else {}))
    for k in KERNELS:
        if not k.signatures:
            continue
        n = 0
        for ll in k.inspect_llvm().values():
            for fn in re.split(r"\ndefine ", ll):
                head = fn.split("(")[0]
                if "cpython" in head or "cfunc" in head or "NRT_" in head[:80]:
                    continue
                n += fn.count("@NRT_incref") + fn.count("@NRT_decref")
        if n:
            opts = k.targetoptions
            kind = "inline" if (opts.get("forceinline") or opts.get("inline")) else ""
            kind += " parallel" if opts.get("parallel") else ""
            print(f"{n:5d}  {k.py_func.__module__}.{k.py_func.__name__}  {kind.strip()}")


if __name__ == "__main__":
    main()
