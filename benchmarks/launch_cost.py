"""What a slot launch (``run_slots``, ``run_threads``, ``start_slots``) costs: a launch of a kernel
that does nothing, a bare round trip through the slot threads' executor, and, inside real frames of
each method, how many launches a frame makes, how late the slot thread starts after the launch and
how late the calling thread sees the last slot's end.

    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/launch_cost.py [--light sphere] [--frames 21]
        [--methods hard,pcss,penumbra-map,soft-shadow-map,occlusion-textures,irregular,layered-attenuation]

Medians in microseconds. On the 2-core virtual machine of docs/results/speed-targets.md
(2026-12-05) a no-op launch took ~52 us, the slot thread started 53-55 us after a frame's launches
and the end was seen 25-39 us late: the host wakes an idle core, and the thread that wakes needs
the GIL the other holds.
"""

from __future__ import annotations

import argparse
import statistics as st
import time

DEFAULT_METHODS = "hard,pcss,penumbra-map,soft-shadow-map,occlusion-textures,irregular,layered-attenuation"


def _median_us(f, n: int) -> float:
    for _ in range(n // 10):
        f()
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return st.median(ts) * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--frames", type=int, default=21)
    ap.add_argument("--methods", default=DEFAULT_METHODS, help="comma-separated")
    a = ap.parse_args()
    import numpy as np

    import softshadows as ss
    from softshadows import _jit

    ss.tune_malloc()  # a benchmark owns its process (softshadows._malloc)

    @_jit.kernel(nogil=True, nrt=False)
    def noop(slot, x, nslot):
        x[slot] += 1.0

    x = np.zeros(8)
    pool = _jit._pool(1)
    print(f"no-op launch on 2 slots: {_median_us(lambda: _jit.run_slots(noop, 2, x, 2), 2000):.0f} us; "
          f"on 1 slot (no thread): {_median_us(lambda: _jit.run_slots(noop, 1, x, 1), 2000):.1f} us; "
          f"an executor round trip: {_median_us(lambda: pool.submit(lambda: None).result(), 2000):.0f} us")  # fmt: skip

    rec = []
    init, finish = _jit.SlotLaunch.__init__, _jit.SlotLaunch.finish

    def timed_init(self, fn, nslot, args, wait_start=True, result=None):
        info = {"launch": time.perf_counter(), "starts": [], "ends": []}

        def slot(s, *rest):
            info["starts"].append((s, time.perf_counter()))
            try:
                return fn(s, *rest)
            finally:
                info["ends"].append((s, time.perf_counter()))

        self._timing = info
        init(self, slot, nslot, args, wait_start, result)

    def timed_finish(self):
        out = finish(self)
        info = getattr(self, "_timing", None)
        if info is not None and "done" not in info:
            info["done"] = time.perf_counter()
            rec.append(info)
        return out

    scene = ss.load_scene(a.scene, light=a.light)
    print(f"{a.scene}, {a.light} light, {a.size}^2, {a.frames} frames a method (medians, us)")
    print(f"{'method':22s} {'launches':>8s} {'slot start':>10s} {'end seen':>9s} {'launch':>8s}")
    _jit.SlotLaunch.__init__, _jit.SlotLaunch.finish = timed_init, timed_finish
    try:
        for m in [m for m in a.methods.split(",") if m]:
            for _ in range(3):
                ss.render(scene, m, a.size, a.size)
            rec.clear()
            for _ in range(a.frames):
                ss.render(scene, m, a.size, a.size)
            late, tail, total = [], [], []
            for info in rec:
                others = [t for s, t in info["starts"] if s >= 1]
                if others:
                    late.append((min(others) - info["launch"]) * 1e6)
                if info["ends"]:
                    tail.append((info["done"] - max(t for _s, t in info["ends"])) * 1e6)
                total.append((info["done"] - info["launch"]) * 1e6)
            print(
                f"{m:22s} {len(rec) / a.frames:8.1f} {st.median(late) if late else float('nan'):10.0f} "
                f"{st.median(tail) if tail else float('nan'):9.0f} {st.median(total):8.0f}"
            )
    finally:
        _jit.SlotLaunch.__init__, _jit.SlotLaunch.finish = init, finish
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
