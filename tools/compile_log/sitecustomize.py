"""Log every Numba compile of a process (and of the warm-up helper it starts) to a file per process.

    SOFTSHADOWS_COMPILE_LOG=DIR PYTHONPATH=tools/compile_log:src python -m softshadows compare bunny
    python tools/compile_timeline.py DIR

Python imports a ``sitecustomize`` module on start-up; with this folder on ``PYTHONPATH`` (the
warm-up helper inherits it) each process writes ``DIR/compile-<pid>.txt``: one line per compile,
start (seconds from the process's start), duration, kernel, argument types (tab-separated), from
Numba's ``numba:compile`` events. Without ``SOFTSHADOWS_COMPILE_LOG`` it does nothing.
"""

import os
import time

if os.environ.get("SOFTSHADOWS_COMPILE_LOG"):
    from numba.core import event

    _out = open(  # noqa: SIM115 (open for the life of the process)
        os.path.join(os.environ["SOFTSHADOWS_COMPILE_LOG"], f"compile-{os.getpid()}.txt"), "w", buffering=1
    )
    _t0 = time.perf_counter()
    _start = {}

    class _Listener(event.Listener):
        def on_start(self, ev):
            _start[id(ev.data["dispatcher"]), str(ev.data["args"])] = time.perf_counter()

        def on_end(self, ev):
            d, args = ev.data["dispatcher"], str(ev.data["args"])
            t1 = time.perf_counter()
            t0 = _start.pop((id(d), args), t1)
            name = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
            _out.write(f"{t0 - _t0:.2f}\t{t1 - t0:.2f}\t{name}\t{args[:200]}\n")

    event.register("numba:compile", _Listener())
