"""Compile every kernel one small ``compare`` needs, from an empty JIT cache, and list each kernel
compiled more than once (with the arguments whose types differ) and the costliest compiles.

    PYTHONPATH=src python tools/kernel_signatures.py [--top 30]

Every extra compile is wasted time on a user's first run (docs/results/cold-start.md). The
compiles are seen through Numba's ``numba:compile`` events, so kernels compiled as callees of
other kernels (which never show up in a dispatcher's ``signatures`` once cached) are counted too.
Typical causes: a literal argument (``0``, ``False``) at one call site and a typed one at another,
read-only and writable arrays (see ``softshadows._jit.frozen``), float32 and float64 scalars.
Takes as long as a cold ``compare`` (minutes).
"""

import argparse
import collections
import os
import re
import sys
import tempfile
import time

ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
ap.add_argument("--top", type=int, default=30, help="list the N kernels that took longest to compile")
a = ap.parse_args()
os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="kernel-signatures-")  # before numba loads
os.environ["SOFTSHADOWS_WARMUP"] = "0"  # one process: every compile is seen here

from numba.core import event  # noqa: E402

records = []  # (seconds, kernel, argument types)


class Listener(event.Listener):
    def __init__(self):
        self.t0 = {}

    def on_start(self, ev):
        self.t0[id(ev.data["dispatcher"]), str(ev.data["args"])] = time.perf_counter()

    def on_end(self, ev):
        d, args = ev.data["dispatcher"], str(ev.data["args"])
        dt = time.perf_counter() - self.t0.pop((id(d), args))
        records.append((dt, f"{d.py_func.__module__}.{d.py_func.__qualname__}", args))


event.register("numba:compile", Listener())
from softshadows.cli import main  # noqa: E402

main(["compare", "bunny", "--size", "64x48", "--samples", "4", "-o", tempfile.mkdtemp(), "-q"])
by_kernel = collections.defaultdict(list)
for dt, name, args in records:
    if not name.startswith("numba."):  # NumPy implementations inside Numba: not ours to change
        by_kernel[name].append((dt, args))
dups = 0
for name, rec in by_kernel.items():
    if len(rec) > 1:
        dups += len(rec) - 1
        print(f"{name}: {len(rec)} compiles ({', '.join(f'{dt:.2f} s' for dt, _ in rec)})")
        parts = [re.split(r", (?![^()]*\))", args.strip("()")) for _, args in rec]
        for i in range(max(map(len, parts))):
            seen = {p[i] if i < len(p) else None for p in parts}
            if len(seen) > 1:
                print(f"    argument {i}: {sorted(str(s) for s in seen)}")
total = collections.Counter()
for name, rec in by_kernel.items():
    total[name] = sum(dt for dt, _ in rec)
print(f"\n{len(by_kernel)} kernels compiled, {dups} extra compiles; the slowest (callees' time included):")
for name, dt in total.most_common(a.top):
    print(f"  {dt:7.2f} s  {name}")
sys.exit(0)
