"""List the kernels compiled by one small ``compare`` and flag those with more than one signature.

    PYTHONPATH=src python tools/kernel_signatures.py

Every extra signature is a duplicate compile on a cold cache (docs/results/cold-start.md).
"""

from softshadows._jit import KERNELS
from softshadows.cli import main

main(["compare", "bunny", "--size", "64x48", "--samples", "4", "-o", "/tmp/kernel-signatures", "-q"])
n = 0
for d in KERNELS:
    if len(d.signatures) > 1:
        print(d.py_func.__module__, d.py_func.__qualname__)
        for s in d.signatures:
            print("    ", s)
    n += len(d.signatures)
print("kernels", len(KERNELS), "called", sum(1 for d in KERNELS if d.signatures), "signatures", n)
