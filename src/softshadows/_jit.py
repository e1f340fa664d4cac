"""One place for the JIT flags of every Numba kernel.

Every kernel is compiled with the same flags (``FLAGS``): cached on disk, IEEE arithmetic
(no fastmath, so results do not depend on the compiler's reassociation), NumPy's error model
(division by zero gives inf/NaN instead of raising, and no zero-checks in hot loops).
Use ``@kernel``, ``@kernel(inline=True)`` (or ``inline="ir"``; with ``nrt=False`` for a hot
helper that takes arrays) or ``@kernel(nogil=True)`` (a slot kernel for :func:`run_slots`: every
parallel loop of the package; ``@kernel(parallel=True)`` still works, but a ``prange`` kernel costs
about a second more to compile).

``inline=True`` has LLVM inline the helper into its callers (Numba's ``forceinline``: the helper is
typed and lowered once, marked ``alwaysinline``, and inlined where its code is linked in);
``inline="ir"`` has Numba inline it in its own IR (``inline="always"``: typed and lowered again at
every call site). V is the same bit for bit either way. IR inlining costs compile time (a cold
``compare`` compiled in a fifth less CPU time with LLVM inlining everywhere). A helper that takes
arrays and runs in an innermost loop should say ``nrt=False`` too: LLVM-inlined with Numba's
reference counting, ``irregular``'s sample-loop helpers ran 1.2-1.3x slower (the increfs and
decrefs of their array arguments stay in the loop), without it as fast as IR-inlined
(docs/results/cold-start.md). ``SOFTSHADOWS_INLINE`` (``ir``, ``llvm``: every helper one way;
``none``: no inlining, frames up to 2x slower) is kept for measuring.

``nrt=False`` compiles without Numba's reference counting. A serial function (a work function
called from a parallel kernel, or a slot kernel run by :func:`run_slots`) otherwise increfs and
decrefs every array its inlined helpers receive, at every iteration: atomic operations that made
such a function up to 2x slower than the same loop inside a parfor (``irregular.scalar_edge_terms``;
``pcss``' slot kernels 1.2x). Such a function must not allocate (Numba says so when it compiles).

``noalias=True`` declares a function's array arguments not to overlap (Numba's ``noalias`` flag,
which it otherwise sets only for a ``prange``'s gufunc: LLVM ``noalias`` on every pointer argument;
kept through LLVM inlining as scoped alias metadata). A vectorized loop that stores into one array
and reads others is then vectorized without run-time overlap checks; without it LLVM compares every
stored array with every other array the loop touches each time the loop starts (soft-shadow-map's
sphere row pass: ~10% of its accumulation, 2 stored x 9 read arrays at every row). Only for helpers
whose callers never pass overlapping arrays.

No kernel gets Numba's C callback ("cfunc") wrapper, and ``inline`` helpers get no CPython wrapper
either: they are only called from kernels, and the wrappers were about a tenth of a cold
``compare``'s compile time (docs/results/cold-start.md). Calling a helper from Python raises a
``TypeError``; tests and scripts call it through ``py_callable(helper)``.

Every kernel is recorded in ``KERNELS`` (the cold-cache check and the warm-up in
:mod:`softshadows._warm`).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import functools
import os
import threading
import time

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.core import codegen as _codegen
from numba.core import typed_passes as _typed_passes
from numba.core.registry import CPUDispatcher
from numba.extending import intrinsic
from numba.np.ufunc import parallel as _parallel
from numba.np.ufunc import wrappers as _wrappers

FLAGS = dict(cache=True, fastmath=False, error_model="numpy")
INLINE = os.environ.get("SOFTSHADOWS_INLINE", "")  # "" (as declared), "ir", "llvm" or "none"
KERNELS: list = []  # every dispatcher made by @kernel, in import order


def kernel(
    fn=None,
    *,
    parallel: bool = False,
    inline: bool | str = False,
    nogil: bool = False,
    nrt: bool = True,
    noalias: bool = False,
):
    """``njit`` with the project's flags (see the module docstring). ``nrt=False``: no reference
    counting of arrays (the function must not allocate); for serial work functions called from a
    parallel kernel's body (see the module docstring). ``noalias=True``: the function's array
    arguments are declared not to overlap (LLVM ``noalias``; see the module docstring)."""
    if inline not in (False, True, "ir"):
        raise ValueError(f"kernel: inline={inline!r} (expected False, True or 'ir')")
    o = dict(FLAGS)
    # compile time (docs/results/cold-start.md): no kernel is used as a C callback or a first-class
    # function, and a helper is called from kernels only (from Python: ``py_callable``)
    o["no_cfunc_wrapper"] = True
    if inline:
        o["no_cpython_wrapper"] = True
    if parallel:
        o["parallel"] = True
    if nogil:
        o["nogil"] = True
    if not nrt:
        o["_nrt"] = False
    if noalias:
        o["_noalias"] = True
    how = INLINE or ("ir" if inline == "ir" else "llvm")
    if inline and how == "ir":
        o["inline"] = "always"
    elif inline and how == "llvm":
        o["forceinline"] = True

    def wrap(f):
        if inline and how == "llvm":
            f._softshadows_link_only = True  # see _link_only_helpers
        d = njit(**o)(f)
        if inline:
            d.__class__ = _Helper
        KERNELS.append(d)
        return d

    if fn is None:
        return wrap
    return wrap(fn)


class _Helper(CPUDispatcher):
    """The dispatcher of an ``inline`` helper: compiled without the CPython wrapper that a call from
    Python needs (Numba would jump to a missing entry point), so a call from Python raises."""

    def __call__(self, *args, **kwargs):
        raise TypeError(
            f"{self.py_func.__qualname__} is a kernel helper: call it from a kernel, or from Python "
            "through softshadows._jit.py_callable"
        )


def _link_only_helpers() -> bool:
    """Machine code only where something calls it. Numba finishes every compiled function by
    generating its machine code, and every caller links the callee's LLVM module in and generates
    that code again in its own. Two kinds of functions are only ever reached that way:

    * an ``inline`` helper (no wrapper: nothing calls it from outside; its callers inline it);
    * a ``prange``'s gufunc and its two wrappers: the kernel calls them by name, linked in, so the
      loop body's code was generated four times (gufunc, both wrappers, kernel) and used once.

    Their libraries are finalised (optimised) without being handed to the JIT engine, and a helper
    is cached on disk as its LLVM module alone (kind ``"softshadows-link"``); the code of every
    kernel, and so V, is the same bit for bit. This reaches into Numba's code generation, so it is
    applied only on the Numba versions it was checked on (``_LINK_ONLY_NUMBA``); ``SOFTSHADOWS_LINK_ONLY=0``
    turns it off for measuring. ``tests/test_warm.py`` checks it; measured in
    docs/results/cold-start.md. Returns whether it is applied (:data:`LINK_ONLY`)."""
    import numba

    if os.environ.get("SOFTSHADOWS_LINK_ONLY", "1") == "0":
        return False
    if tuple(int(x) for x in numba.__version__.split(".")[:2]) not in _LINK_ONLY_NUMBA:
        return False
    lowering = _typed_passes.BaseNativeLowering
    lib_cls = _codegen.JITCodeLibrary
    if getattr(lib_cls, "_softshadows_patched", False):
        return True
    run_pass = lowering.run_pass
    finalize_final = lib_cls._finalize_final_module
    serialize = lib_cls.serialize_using_object_code
    unserialize = lib_cls._unserialize.__func__
    set_env = _codegen.JITCPUCodegen.set_env

    def lowering_run_pass(self, state):
        link_only = getattr(state.func_id.func, "_softshadows_link_only", False)
        # a prange's gufunc: only ever linked into its kernel (through the two wrappers below)
        link_only = link_only or state.func_id.func_qualname.startswith("__numba_parfor_gufunc")
        if state.library is None and link_only:
            state.library = state.targetctx.codegen().create_library(state.func_id.func_qualname)
            state.library.enable_object_caching()
            state.library._softshadows_link_only = True
        return run_pass(self, state)

    def finalize_final_module(self):
        if not getattr(self, "_softshadows_link_only", False):
            return finalize_final(self)
        self._finalize_dynamic_globals()
        self._verify_declare_only_symbols()
        self._finalized = True

    def serialize_using_object_code(self):
        if not getattr(self, "_softshadows_link_only", False):
            return serialize(self)
        self._ensure_finalized()
        return (self.name, "softshadows-link", self._get_module_for_linking().as_bitcode())

    def _unserialize(cls, codegen, state):
        name, kind, data = state
        if kind != "softshadows-link":
            return unserialize(cls, codegen, state)
        lib = codegen.create_library(name)
        lib._softshadows_link_only = True
        lib._final_module = _codegen.ll.parse_bitcode(data)
        lib._finalize_final_module()
        return lib

    def codegen_set_env(self, env_name, env):
        if self._engine.get_global_value_address(env_name):  # a link-only helper has none
            set_env(self, env_name, env)

    def compile_wrapper(self, wrapper_name):
        lib = compile_gufunc_wrapper(self, wrapper_name)
        if self.is_parfors:  # linked into the kernel, never called through a pointer
            lib._softshadows_link_only = True
        return lib

    def build_gufunc_wrapper(py_func, cres, sin, sout, cache, is_parfors):
        info = build_parallel_wrapper(py_func, cres, sin, sout, cache, is_parfors)
        if is_parfors:  # the same: the kernel calls it by name, linked in
            info.library._softshadows_link_only = True
        return info

    compile_gufunc_wrapper = _wrappers._GufuncWrapper._compile_wrapper
    build_parallel_wrapper = _parallel.build_gufunc_wrapper
    _wrappers._GufuncWrapper._compile_wrapper = compile_wrapper
    _parallel.build_gufunc_wrapper = build_gufunc_wrapper
    lowering.run_pass = lowering_run_pass
    lib_cls._finalize_final_module = finalize_final_module
    lib_cls.serialize_using_object_code = serialize_using_object_code
    lib_cls._unserialize = classmethod(_unserialize)
    _codegen.JITCPUCodegen.set_env = codegen_set_env
    lib_cls._softshadows_patched = True
    return True


def _noalias_option() -> None:
    """Numba compiles with its ``noalias`` flag (LLVM ``noalias`` on every pointer argument) only
    for parallel gufuncs and offers no decorator option for it: ``_noalias`` maps it."""
    from numba.core.cpu import CPUTargetOptions
    from numba.core.options import TargetOptions

    if not hasattr(CPUTargetOptions, "_noalias"):
        CPUTargetOptions._noalias = TargetOptions.Mapping("noalias")


_noalias_option()


def _cache_writes_may_fail() -> None:
    """A kernel whose on-disk cache cannot be written (a file-size limit, a full disk or quota, a
    read-only checkout) is used as compiled, with one warning, instead of failing the whole run:
    Numba raises the write's ``OSError`` from the compile (outside Windows), which reached the user
    as an unrelated one-line error (e.g. "File too large" before the image was written). The next
    run compiles the kernel again. Only this package's kernels (and those of a copy of it imported
    under a name that starts with ``softshadows``): other Numba code in the process is left as it
    was."""
    from numba.core import caching

    save = caching.Cache.save_overload
    if getattr(save, "_softshadows", False):
        return
    warned = []

    def save_overload(self, sig, data):
        try:
            save(self, sig, data)
        except OSError as exc:
            if not getattr(getattr(self, "_py_func", None), "__module__", "").startswith("softshadows"):
                raise
            if not warned:
                warned.append(True)
                import warnings

                why = exc.strerror or str(exc)
                warnings.warn(
                    f"the compiled kernels could not be cached ({why}): they compile again on the next run",
                    stacklevel=2,
                )

    save_overload._softshadows = True
    caching.Cache.save_overload = save_overload


_cache_writes_may_fail()

_LINK_ONLY_NUMBA = {(0, 68)}  # Numba versions whose code generation _link_only_helpers was checked on
LINK_ONLY = _link_only_helpers()  # whether helpers and gufuncs are compiled without machine code


@functools.cache
def py_callable(helper):
    """A Python-callable kernel that calls ``helper`` (an ``inline`` kernel) with its arguments: for
    tests and scripts. One per helper and process (compiled per process, not cached on disk)."""

    @njit(cache=False, error_model="numpy")
    def call(*args):
        return helper(*args)

    return call


_POOL = None  # the slot threads: (executor, its size, the process that made it)
_POOL_LOCK = threading.Lock()


def _pool(n: int):
    """At least n slot threads (made again in a forked child, which does not inherit them)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL[1] < n or _POOL[2] != os.getpid():
            _POOL = (
                concurrent.futures.ThreadPoolExecutor(max_workers=n, thread_name_prefix="softshadows-slot"),
                n,
                os.getpid(),
            )
        return _POOL[0]


def run_slots(fn, nslot: int, *args) -> None:
    """``fn(slot, *args)`` for every slot in ``range(nslot)``, one slot per thread (the calling
    thread takes slot 0): what ``for slot in prange(nslot): ...`` does with one slot per Numba
    thread, without Numba's parfor. ``fn`` is a serial ``@kernel(nogil=True)`` (it runs on Python
    threads with the GIL released) and uses ``slot`` as its thread index (e.g. for its scratch).

    Why: Numba compiles a parallel kernel's body twice (the kernel and the gufunc of its prange)
    and LLVM optimises and generates the code of everything the body calls again in each of the
    two, so a large parallel kernel cost about twice its body's compile time
    (docs/results/cold-start.md); even a small prange kernel cost about 1 s more compile CPU than
    the same loop run this way, so every parallel loop of the package is a slot kernel. A launch
    costs about 20 microseconds more than a prange's: run a loop of a few tens of microseconds as
    one slot on the calling thread (``fn(0, ..., 1)``) instead."""
    nslot = int(nslot)
    if nslot <= 1:
        fn(0, *args)
        return
    SlotLaunch(fn, nslot, args, wait_start=False).finish()


#: how long :class:`SlotLaunch` waits for its slot threads to start (an idle host: ~0.1 ms)
_START_WAIT_S = 0.0003


class SlotLaunch:
    """A :func:`run_slots` launch split in two (:func:`start_slots`): slots 1 to n-1 run on the
    slot threads from the start; :meth:`finish` runs slot 0 on the calling thread and waits for the
    others. Between the two the calling thread is free for serial work, which then overlaps the
    kernel: for a kernel that takes its items from a shared work queue (:func:`next_item`), the
    calling thread joins late and takes whatever items are left. ``result``: what ``finish()``
    returns (a function of no arguments, called once the slots are done)."""

    def __init__(self, fn, nslot: int, args: tuple, wait_start: bool = True, result=None, on_finish=None):
        self._fn, self._args, self._result, self._finished = fn, args, result, False
        self._on_finish = on_finish
        if nslot <= 1:
            self._futs = []
            return
        if not wait_start:
            self._futs = [_pool(nslot - 1).submit(fn, s, *args) for s in range(1, nslot)]
            return
        started = threading.Semaphore(0)

        def slot(s):
            started.release()
            fn(s, *args)  # (holds the GIL until the kernel releases it: its dispatch)

        self._futs = [_pool(nslot - 1).submit(slot, s) for s in range(1, nslot)]
        # wait a little, without the GIL, for the slot threads to take it: a thread that wakes while
        # the calling thread runs Python would wait for the GIL until the calling thread releases
        # it (measured: a third of a millisecond on `irregular`'s frame); not longer, so that a slot
        # thread held up by the host does not hold up the calling thread's work too
        deadline = time.perf_counter() + _START_WAIT_S
        for _ in self._futs:
            if not started.acquire(timeout=max(deadline - time.perf_counter(), 0.0)):
                break

    def finish(self):
        """Slot 0 on the calling thread, then wait for every slot (before anything is raised);
        returns ``result()``. Runs once: a second call only returns the result, so that a caller
        can finish in a ``finally`` whether or not its overlapping work raised."""
        if not self._finished:
            self._finished = True
            try:
                if self._on_finish is not None:
                    self._on_finish()
                self._fn(0, *self._args)
            finally:
                for f in self._futs:
                    f.exception()  # wait for every slot before anything is raised
            for f in self._futs:
                f.result()
        return self._result() if self._result is not None else None


def start_slots(fn, nslot: int, *args, result=None, on_finish=None) -> SlotLaunch:
    """Start ``fn(slot, *args)`` for slots 1 to nslot-1 on the slot threads and return the launch;
    its ``finish()`` runs slot 0 on the calling thread, waits and returns ``result()``
    (:class:`SlotLaunch`). Until then, the slot threads are busy: the calling thread must not
    launch other slot kernels on them (it runs them alone, :func:`calling_thread_only`), or they
    would wait for this one. ``on_finish``: called first in ``finish()`` (e.g. :meth:`SharedWork.close`,
    which lets slot threads that wait in it go)."""
    return SlotLaunch(fn, int(nslot), args, result=result, on_finish=on_finish)


class SharedWork:
    """Work that the calling thread offers to the slot threads of a :func:`start_slots` launch that
    finish theirs early: a slot thread calls :meth:`help` after its own part (the launch's slot
    function wraps the kernel, see ``penumbra_map.start_eye_lookups``) and waits there for offers;
    the calling thread calls :meth:`run` with a kernel whose items are claimed from a shared
    counter (:func:`next_item`), as often as it has such work, and :meth:`close` once it has no
    more (before it joins the launch: the launch's ``on_finish``). ``run`` runs the kernel on the
    calling thread and on every slot thread that is waiting in ``help`` or comes to it while the
    kernel runs, and returns once all of them are done: the same items computed, whoever computes
    them, so that the outcome never depends on the timing, only the time it takes. A slot thread
    that comes after the calling thread's part has run out of items waits for the next offer.
    Made for the calling thread's serial work that overlaps a launch (:func:`calling_thread_only`)
    when the launch ends first: `penumbra-map`'s eye lookups end ~0.7 ms before the calling
    thread's sheets and cones do on `bunny` (a helper that left when it found no offer open left
    a core idle meanwhile, 2026-12-05)."""

    def __init__(self):
        self._cond = threading.Condition()
        self._task = None
        self._offers = 0  # offers made so far (a helper serves each at most once)
        self._closed = False
        self._helpers = 0

    def help(self, slot: int) -> None:
        """From slot thread ``slot`` (>= 1) of the launch: run each kernel offered from now on with
        this slot, until :meth:`close`."""
        served = 0
        while True:
            with self._cond:
                while not self._closed and (self._task is None or self._offers == served):
                    self._cond.wait()
                if self._closed:
                    return  # (the calling thread closes once its offers are done)
                served = self._offers
                self._helpers += 1
                fn, args, nslot = self._task
            try:
                fn(slot, *args, nslot)
            finally:
                with self._cond:
                    self._helpers -= 1
                    self._cond.notify_all()

    def run(self, fn, nslot: int, *args) -> None:
        """Offer ``fn(slot, *args, nslot)`` (its items claimed from a counter in ``args``) and run
        it as slot 0 on the calling thread; return when every slot thread that joined is done.
        After :meth:`close`, it runs on the calling thread alone."""
        with self._cond:
            if not self._closed:
                self._task = (fn, args, int(nslot))
                self._offers += 1
                self._cond.notify_all()
        try:
            fn(0, *args, int(nslot))
        finally:
            with self._cond:
                self._task = None
                while self._helpers:
                    self._cond.wait()

    def close(self) -> None:
        """No more offers: every waiting helper leaves (idempotent)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


@contextlib.contextmanager
def calling_thread_only():
    """Within: :func:`run_threads` (and every launch sized by ``numba.get_num_threads()``) runs one
    slot, on the calling thread (``numba.set_num_threads`` is per thread). For serial work that
    overlaps a :func:`start_slots` launch. Slot kernels give the same bits whatever their slot
    count."""
    import numba

    n = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(n)


@intrinsic
def next_item(typingctx, counter):
    """Atomic ``counter[0] += 1`` (int64, sequentially consistent), returning the old value: a work
    queue shared by the slots of a ``run_slots`` kernel, each taking the next item until none is
    left (see :func:`work_counter`). Numba has no atomics; this is one LLVM ``atomicrmw add``."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64 and counter.ndim == 1):
        return None

    def codegen(context, builder, sig, args):
        ary = context.make_array(sig.args[0])(context, builder, args[0])
        return builder.atomic_rmw("add", ary.data, ir.Constant(ir.IntType(64), 1), "seq_cst")

    return types.int64(counter), codegen


def work_counter() -> np.ndarray:
    """A fresh counter for :func:`next_item` (one per launch): items are claimed from 0 on."""
    return np.zeros(1, np.int64)


def host_has_avx512f(default: bool = False) -> bool:
    """Whether this host's CPU has AVX-512F, as LLVM sees it (``default`` when it cannot say)."""
    try:
        from llvmlite import binding

        return bool(binding.get_host_cpu_features().get("avx512f", False))
    except Exception:  # pragma: no cover - no feature query
        return default


def _host_has_avx512() -> bool:
    """Whether the kernels are compiled for this host (Numba's default CPU) and it has AVX-512F (the
    vector compress of :func:`compact_indices`). A portable target (``NUMBA_CPU_NAME``) gets the
    scalar loop, as a host that cannot say."""
    from numba.core import config

    return config.CPU_NAME in (None, "host") and host_has_avx512f(default=False)


#: :func:`compact_indices` packs 8 flags at a time with AVX-512's ``vpcompressq`` (register form)
HAS_AVX512 = _host_has_avx512()


@intrinsic
def _compress8(typingctx, keep, i0, base, out, m):
    """``out[m:m + 8]`` := base + q for the q in 0..7 with ``keep[i0 + q]`` != 0, in order, packed
    to the front (the 8 stores are written whole: the rest of them is garbage); returns how many.
    ``keep`` int8 (8 bytes from ``i0`` readable), ``out`` int64 (8 entries from ``m`` writable).
    The register form of AVX-512's compress and one vector store: LLVM's generic
    ``llvm.masked.compressstore`` is the memory form, microcoded on AMD Zen 4 (2.5x slower than the
    scalar loop there; this, 4x faster than it)."""
    if not (
        isinstance(keep, types.Array)
        and keep.dtype == types.int8
        and isinstance(out, types.Array)
        and out.dtype == types.int64
    ):
        return None

    def codegen(context, builder, sig, args):
        k = context.make_array(sig.args[0])(context, builder, args[0])
        o = context.make_array(sig.args[3])(context, builder, args[3])
        i8, i32, i64 = ir.IntType(8), ir.IntType(32), ir.IntType(64)
        v8i8, v8i64 = ir.VectorType(i8, 8), ir.VectorType(i64, 8)
        flags = builder.load(builder.bitcast(builder.gep(k.data, [args[1]]), v8i8.as_pointer()), align=1)
        mask = builder.icmp_unsigned("!=", flags, ir.Constant(v8i8, [0] * 8))
        b = builder.insert_element(ir.Constant(v8i64, ir.Undefined), args[2], ir.Constant(i32, 0))
        b = builder.shuffle_vector(b, ir.Constant(v8i64, ir.Undefined), ir.Constant(ir.VectorType(i32, 8), [0] * 8))
        vals = builder.add(b, ir.Constant(v8i64, list(range(8))))
        fnty = ir.FunctionType(v8i64, [v8i64, v8i64, mask.type])
        comp = builder.call(
            cgutils.get_or_insert_function(builder.module, fnty, "llvm.x86.avx512.mask.compress.v8i64"),
            [vals, ir.Constant(v8i64, [0] * 8), mask],
        )
        builder.store(comp, builder.bitcast(builder.gep(o.data, [args[4]]), v8i64.as_pointer()), align=8)
        pop = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i8, [i8]), "llvm.ctpop.i8")
        return builder.zext(builder.call(pop, [builder.bitcast(mask, i8)]), i64)

    return types.int64(keep, types.int64, types.int64, out, types.int64), codegen


@kernel(inline=True, nrt=False)
def _compact_indices_avx512(keep, n, base, out, m):
    i = 0
    while i + 8 <= n:
        m += _compress8(keep, np.int64(i), np.int64(base + i), out, np.int64(m))
        i += 8
    for q in range(i, n):
        out[np.uint64(m)] = base + q
        m += keep[q]
    return m


@kernel(inline=True, nrt=False)
def _compact_indices_scalar(keep, n, base, out, m):
    for q in range(n):
        out[np.uint64(m)] = base + q  # unsigned: no wrap-around code
        m += keep[q]
    return m


#: ``compact_indices(keep, n, base, out, m)``: ``out[m:]`` := base + q for the q < n with
#: ``keep[q]`` = 1 (int8 flags, 0 or 1), in order; returns m + their count. ``out`` needs 8 entries of
#: slack past its last (whole 8-lane stores). The same values either way; on an AVX-512 host 8
#: flags at a time (:func:`_compress8`), else a branch-free loop (a store per flag, the position
#: advanced by it).
compact_indices = _compact_indices_avx512 if HAS_AVX512 else _compact_indices_scalar


def run_threads(fn, *args) -> None:
    """:func:`run_slots` with one slot per Numba thread, the slot count passed last as well:
    ``fn(slot, *args, n)`` for slot in ``range(n)``, n = ``numba.get_num_threads()`` (the usual
    signature of the package's slot kernels)."""
    import numba

    n = numba.get_num_threads()
    run_slots(fn, n, *args, n)


def frozen(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (no copy). Numba compiles a separate specialisation of a kernel for
    a read-only and a writable array of the same dtype and layout: an input that comes both ways
    (a scene's cached geometry is read-only, a caller's arrays are not) is passed frozen, so that
    the kernel compiles once."""
    v = a.view()
    v.flags.writeable = False
    return v


@kernel(inline=True)
def row_stride(n):
    """A row length >= ``n`` for a float64 scratch (rows, length) that a loop reads and writes
    column by column, many rows per column: the shortest whole, odd number of 64-byte lines. With
    a power-of-two length (e.g. 256: 2 KiB) a column's rows fall in one or two L1 cache sets, and
    more rows than the cache's 8 ways evict each other (``irregular``'s error-bound pass, 17 rows
    of 256: its kernel 0.92-0.94x the time with 264)."""
    lines = (n + 7) // 8
    return 8 * (lines + 1 - lines % 2)
