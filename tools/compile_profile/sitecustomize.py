"""Exclusive compile time per kernel and per Numba pass, for every process of a run (the warm-up
helper included), from Numba's ``numba:compile``, ``numba:run_pass`` and ``numba:llvm_lock`` events:

    SOFTSHADOWS_COMPILE_PROFILE=DIR PYTHONPATH=tools/compile_profile:src python -m softshadows compare bunny
    python tools/compile_profile/report.py DIR

"Exclusive": a kernel's time without the compiles of its callees (which Numba compiles while it
types the caller); the passes of a parallel kernel's gufunc are listed as ``KERNEL [gufunc]``. The
LLVM time (time holding llvmlite's lock) is counted per kernel. Each process writes
``DIR/cprof-<pid>.json`` at exit. Without ``SOFTSHADOWS_COMPILE_PROFILE`` it does nothing.
"""

import atexit
import collections
import json
import os
import time

if os.environ.get("SOFTSHADOWS_COMPILE_PROFILE"):
    from numba.core import event

    _stack = []  # [kind, label, start, time of children]
    _excl = collections.Counter()  # (kernel, pass) -> exclusive seconds
    _llvm = collections.Counter()  # (kernel, pass) -> seconds holding the LLVM lock

    def _innermost(kind):
        for f in reversed(_stack):
            if f[0] == kind:
                return f[1]
        return "<none>"

    class _Frames(event.Listener):
        def __init__(self, kind):
            self.kind = kind

        def on_start(self, ev):
            if self.kind == "compile":
                d = ev.data["dispatcher"]
                label = f"{d.py_func.__module__}.{d.py_func.__qualname__} {str(ev.data['args'])[:80]}"
            else:
                label = ev.data["name"].split(" [")[0]
                _stack.append(["qual", ev.data["qualname"], 0.0, 0.0])
            _stack.append([self.kind, label, time.perf_counter(), 0.0])

        def on_end(self, ev):
            kind, label, t0, child = _stack.pop()
            dur = time.perf_counter() - t0
            kernel = _innermost("compile")
            if kind == "pass":
                qual = _stack.pop()[1]
                gufunc = qual.startswith("__numba_parfor_gufunc")
                _excl[(kernel + (" [gufunc]" if gufunc else ""), label)] += dur - child
            else:
                _excl[(label, "<compile, outside passes>")] += dur - child
            if _stack:
                _stack[-1][3] += dur

    class _Llvm(event.Listener):
        t0 = 0.0

        def on_start(self, ev):
            _Llvm.t0 = time.perf_counter()

        def on_end(self, ev):
            _llvm[(_innermost("compile"), _innermost("pass"))] += time.perf_counter() - _Llvm.t0

    event.register("numba:compile", _Frames("compile"))
    event.register("numba:run_pass", _Frames("pass"))
    event.register("numba:llvm_lock", _Llvm())

    @atexit.register
    def _dump():
        path = os.path.join(os.environ["SOFTSHADOWS_COMPILE_PROFILE"], f"cprof-{os.getpid()}.json")
        with open(path, "w") as fh:
            json.dump({"excl": [[*k, v] for k, v in _excl.items()], "llvm": [[*k, v] for k, v in _llvm.items()]}, fh)
