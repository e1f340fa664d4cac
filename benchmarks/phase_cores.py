"""Where a method's frame leaves a core idle: per timed phase (``Timer.phase``), its wall time, the
process CPU time spent meanwhile (every thread) and the idle core time, threads x wall - CPU.

    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/phase_cores.py penumbra-map,irregular [--light sphere] [--frames 31]

A phase that runs on one thread while the others wait (serial set-up before a launch, a launch
whose slots end unequally, work on the calling thread that outlasts a started launch) shows as
idle core time; `benchmarks/slot_balance.py` then tells which launch. Found this way on
2026-12-04: `penumbra-map`'s eye lookups ending ~1 ms before its cones' rejection (2.9 ms idle in
`penumbra_map`, now shared through `_jit.SharedWork`) and `irregular`'s umbra set-up on the
calling thread (0.7 ms in `hard_kernel`). Frames are rendered method by method after warm-up; the
per-phase numbers are means over the frames. On a host whose two "cores" share one physical
core, two busy threads do not run twice as fast as one: idle time is an upper bound of what
overlapping can win.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("methods", help="comma-separated method names")
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--frames", type=int, default=31)
    a = ap.parse_args(argv)
    import numba

    import softshadows as ss
    from softshadows.methods import base

    ss.tune_malloc()  # a benchmark owns its process (softshadows._malloc)
    threads = numba.get_num_threads()
    wall = collections.defaultdict(float)
    cpu = collections.defaultdict(float)

    @contextlib.contextmanager
    def phase(self, name):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            dt = time.perf_counter() - t0
            self.times[name] = self.times.get(name, 0.0) + dt
            wall[name] += dt
            cpu[name] += time.process_time() - c0

    base.Timer.phase = phase
    scene = ss.load_scene(a.scene, light=a.light)
    n = a.frames
    print(f"{a.scene} {a.light} {a.size}^2, {n} frames, {threads} threads: means in ms")
    for m in a.methods.split(","):
        for _ in range(3):  # compile and warm up
            ss.render(scene, m, a.size, a.size)
        wall.clear()
        cpu.clear()
        tw = tc = 0.0
        for _ in range(n):
            t0, c0 = time.perf_counter(), time.process_time()
            ss.render(scene, m, a.size, a.size)
            tw += time.perf_counter() - t0
            tc += time.process_time() - c0
        print(f"{m}: frame {1e3 * tw / n:.2f} wall, {1e3 * tc / n:.2f} CPU, cores used {tc / tw / threads:.2f}")
        print(f"  {'phase':18s} {'wall':>7s} {'CPU':>7s} {'idle core':>9s}")
        for k in wall:
            w, c = 1e3 * wall[k] / n, 1e3 * cpu[k] / n
            print(f"  {k:18s} {w:7.2f} {c:7.2f} {threads * w - c:9.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
