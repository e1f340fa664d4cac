"""How long each slot of every multi-slot launch (``run_slots``, ``run_threads``) of a method's
frame waits for the others: the end time of each slot, from the launch's start, over whole
frames, and the time lost to the slowest slot (its end minus the mean end, per launch).

    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/slot_balance.py soft-shadow-map --light rect
    PYTHONPATH=src python benchmarks/slot_balance.py irregular --light sphere --frames 31 --min-lost 0

Frame-level A/B runs on a shared host resolve a few per cent at best; a slot that idles while the
other finishes is a direct measurement, taken inside real frames: a replay of `soft-shadow-map`'s
accumulation on saved inputs had shown one of two slots idle for 5.8 ms (it had zeroed the receiver
depths along with the map it reset), where this script measured at most ~0.3 ms
(docs/results/speed-targets.md, 2026-12-04). Launches started with ``start_slots`` (a calling
thread that joins late on purpose) are not timed.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("method")
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--frames", type=int, default=21)
    ap.add_argument("--min-lost", type=float, default=0.1, help="list launches losing at least this many ms")
    a = ap.parse_args()
    import numpy as np

    import softshadows as ss
    from softshadows import _jit

    ss.tune_malloc()  # a benchmark owns its process (softshadows._malloc)
    scene = ss.load_scene(a.scene, light=a.light)
    ss.render(scene, a.method, a.size, a.size)  # compile and warm up
    orig = _jit.run_slots
    ends = collections.defaultdict(list)

    def timed(fn, n, *args):
        if int(n) <= 1:
            return orig(fn, n, *args)
        t0 = time.perf_counter()
        end = [0.0] * int(n)

        def slot(s, *aa):  # the kernel, then its slot's end time
            fn(s, *aa)
            end[s] = time.perf_counter() - t0

        orig(slot, n, *args)
        ends[getattr(fn, "__name__", str(fn))].append(end)

    patched = [
        m
        for name, m in list(sys.modules.items())
        if name.startswith("softshadows") and getattr(m, "run_slots", None) is orig
    ]
    for m in patched:
        m.run_slots = timed
    try:
        for _ in range(a.frames):
            ss.render(scene, a.method, a.size, a.size)
    finally:
        for m in patched:
            m.run_slots = orig
    print(f"{a.method}, {a.scene} {a.light} {a.size}^2, {a.frames} frames: per launch, medians in ms")
    print(f"{'kernel':36s} {'launches':>8s} {'slowest end':>11s} {'lost':>6s}  slot ends")
    rows = []
    for name, v in ends.items():
        e = np.asarray(v) * 1e3  # (launches, slots)
        lost = float(np.median(e.max(1) - e.mean(1)))
        rows.append((lost, name, e))
    for lost, name, e in sorted(rows, key=lambda r: -r[0]):
        if lost < a.min_lost:
            continue
        per = " ".join(f"{x:.2f}" for x in np.median(e, axis=0))
        launches = e.shape[0] / a.frames
        print(f"{name:36s} {launches:8.1f} {np.median(e.max(1)):11.2f} {lost:6.2f}  {per}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
