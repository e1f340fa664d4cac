"""Print the compile timeline of each process logged by ``tools/compile_log`` (see its docstring):
the top-level compiles of 1.5 s or more (start and duration, seconds from the process's start),
the time each process spent compiling, and the kernels compiled by more than one process.

    python tools/compile_timeline.py DIR [--min 1.5]
"""

import argparse
import glob
import os

ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
ap.add_argument("folder")
ap.add_argument("--min", type=float, default=1.5, help="list top-level compiles of at least this many seconds")
a = ap.parse_args()
seen = []
for path in sorted(glob.glob(os.path.join(a.folder, "compile-*.txt"))):
    rows = []
    with open(path) as fh:
        for line in fh:
            t0, dt, name, args = line.rstrip("\n").split("\t")
            rows.append((float(t0), float(dt), name, args))
    rows.sort()
    top, end = [], -1.0
    for t0, dt, name, _ in rows:
        if t0 >= end - 1e-9:  # not nested in the previous top-level compile
            top.append((t0, dt, name))
            end = t0 + dt
    busy = sum(dt for _, dt, _ in top)
    print(f"{os.path.basename(path)}: {len(rows)} compiles, busy compiling {busy:.1f} s, last ends at {end:.1f} s")
    for t0, dt, name in top:
        if dt >= a.min:
            print(f"  {t0:6.1f} {dt:5.1f}  {name.removeprefix('softshadows.')}")
    seen.append({(name, args) for _, _, name, args in rows if not name.startswith("numba.")})
if len(seen) > 1:
    both = set.intersection(*seen)
    print(f"compiled in more than one process: {len(both)}", *sorted(n for n, _ in both), sep="\n  ")
