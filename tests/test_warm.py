"""The cold-cache check and the first-run message (softshadows._warm), in a fresh process with an
empty NUMBA_CACHE_DIR (nothing is compiled: the check only reads the cache indexes)."""

import os
import subprocess
import sys

import pytest

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src")

PROBE = """
import io
from softshadows.compare import resolve_methods
from softshadows import _warm
resolve_methods("all")  # imports every method module, so every kernel is registered
buf = io.StringIO()
a = _warm.say_if_cold(buf)
b = _warm.say_if_cold(buf)
print(a, b, _warm.cache_state(), repr(buf.getvalue()))
print(_warm.start_warmup("bunny", "rect", 16, 16, ["hard"], {}))
"""


def _probe(cache_dir, **env):
    e = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), PYTHONPATH=SRC, **env)
    return subprocess.run([sys.executable, "-c", PROBE], env=e, capture_output=True, text=True, check=True).stdout


def test_empty_cache_is_cold_and_said_once(tmp_path):
    out = _probe(tmp_path, SOFTSHADOWS_WARMUP="0").splitlines()
    # cold both times, (cold, writable), and the message exactly once
    assert out[0] == f"True True (True, True) {_message()!r}", out
    assert out[1] == "None"  # SOFTSHADOWS_WARMUP=0: no helper process


def _message():
    sys.path.insert(0, SRC)
    from softshadows._warm import COLD_MESSAGE

    return COLD_MESSAGE + "\n"


def test_helper_warms_the_signatures_the_real_calls_use():
    # the helper compiles the depth, fragment and min-blend tile kernels on dummy inputs
    # (softshadows._warm.warm_raster_modes); that is only worth it if the real calls then reuse
    # those compiled overloads. A dtype or layout that drifts (a FrontEnd field changed, say) would
    # make a real call compile a second signature: the real (perspective) calls must add none.
    # (Orthographic views are a signature of their own, FrontEnd.kind: another test in this
    # process may have compiled them already.)
    import numpy as np

    sys.path.insert(0, SRC)
    import softshadows
    from softshadows._warm import warm_raster_modes
    from softshadows.api import eye_view
    from softshadows.raster import rasterize_depth, rasterize_fragments, rasterize_min_blend
    from softshadows.raster import rasterizer as r
    from softshadows.raster.programs import PROGRAM_PENUMBRA

    kernels = [r._tiles_depth_slot, r._tiles_count_slot, r._tiles_fragments_slot, r._MIN_BLEND_SLOT_PENUMBRA]
    warm_raster_modes()
    warmed = [set(k.signatures) for k in kernels]
    assert all(warmed)
    sc = softshadows.load_scene("spheres")
    view = eye_view(sc, 32, 24)
    V, F = sc.flat.vertices, sc.flat.faces
    depth, _ = rasterize_depth(view, V, F, cull="back")
    frags = rasterize_fragments(view, V, F)
    assert np.isfinite(depth).any() and len(frags.pixel) > 0  # the real calls drew something
    out = np.full((24, 32), np.inf, np.float32)
    p = PROGRAM_PENUMBRA  # the one program the methods use (penumbra-map)
    rasterize_min_blend(view, V, F, p, np.ones((len(F), 3)), np.zeros((24, 32), np.float32), np.zeros(3), out)
    assert [set(k.signatures) for k in kernels] == warmed


def test_claims_give_each_method_to_one_process(tmp_path):
    # the main process and the helper claim methods from opposite ends of the list; a method
    # claimed by one must be refused to the other, whichever asks first
    sys.path.insert(0, SRC)
    from softshadows._warm import Claims

    a, b = Claims(str(tmp_path)), Claims(str(tmp_path))
    assert a.claim("hard") and not b.claim("hard") and not a.claim("hard")
    assert b.claim("pcss") and not a.claim("pcss")
    assert not a.is_done("pcss")
    b.done("pcss")
    assert a.is_done("pcss")


def _render_all_with_helper(monkeypatch, names, helpers, cached):
    """compare._render_all over ``names`` with a fake helper that has claimed ``helpers`` and
    reports ``cached(name, calls)``, and a fake render: (the calls in order, results, failed)."""
    sys.path.insert(0, SRC)
    from types import SimpleNamespace

    import softshadows
    from softshadows import compare

    calls = []

    class FakeHelper:
        def claim(self, name):
            return name not in helpers

        def cached(self, name):
            return cached(name, calls)

        def wait(self, name):
            calls.append(("wait", name))

    def fake_render(sc, m, w, h, **kw):
        calls.append(("render", m))
        return m

    monkeypatch.setattr(softshadows, "render", fake_render)
    resolved = {m: {} for m in names} | {"ground-truth": {"samples": 4}}
    sc = SimpleNamespace(name="s", light=SimpleNamespace(shape="rect"))
    _gt, results, failed = compare._render_all(
        sc, names, resolved, 8, 8, 0, None, False, lambda msg: None, FakeHelper()
    )
    return calls, results, failed


def test_main_process_renders_the_helpers_methods_last_in_the_original_order(monkeypatch):
    # with a helper that has claimed the last two methods and is still compiling them while the
    # main process renders its own, the main process renders the others first, then waits for
    # each of the helper's (its kernels cached) before rendering it; the results keep the order of
    # the method list
    names = ["hard", "pcss", "penumbra-map", "layered-attenuation"]
    calls, results, failed = _render_all_with_helper(
        monkeypatch, names, ("penumbra-map", "layered-attenuation"), lambda name, calls: False
    )
    # each method twice (an untimed first frame, then the timed one)
    expect = [("render", "ground-truth")]
    for m in ("hard", "pcss"):
        expect += [("render", m)] * 2
    for m in ("penumbra-map", "layered-attenuation"):
        expect += [("wait", m)] + [("render", m)] * 2
    assert calls == expect
    assert list(results) == names and not failed


def test_main_process_renders_a_helper_method_as_soon_as_it_is_cached(monkeypatch):
    # the helper has claimed the last method of the list and cached it once the main process has
    # rendered "hard" (the first of its own): the main process renders it right then, without
    # waiting, instead of at the end of the list; a helper method not yet cached is still waited
    # for at the end
    names = ["hard", "irregular", "pcss", "coherent-raytrace"]
    calls, results, failed = _render_all_with_helper(
        monkeypatch,
        names,
        ("coherent-raytrace", "irregular"),
        lambda name, calls: name == "coherent-raytrace" and ("render", "hard") in calls,
    )
    expect = [("render", "ground-truth")] + [("render", "hard")] * 2 + [("render", "coherent-raytrace")] * 2
    expect += [("render", "pcss")] * 2 + [("wait", "irregular")] + [("render", "irregular")] * 2
    assert calls == expect
    assert list(results) == names and not failed


def test_front_end_compiles_once_for_read_only_and_writable_geometry():
    # a scene's cached geometry is read-only, a caller's arrays are writable: Numba would compile
    # each front-end kernel twice (once per flag) on a cold cache unless the rasterizer freezes
    # its inputs (softshadows._jit.frozen)
    import numpy as np

    sys.path.insert(0, SRC)
    import softshadows
    from softshadows.api import eye_view
    from softshadows.raster import rasterize_depth
    from softshadows.raster import rasterizer as r

    sc = softshadows.load_scene("spheres")
    view = eye_view(sc, 32, 24)
    V, F = sc.flat.vertices.copy(), sc.flat.faces.copy()
    d1, _ = rasterize_depth(view, V, F)
    V.flags.writeable = F.flags.writeable = False
    d2, _ = rasterize_depth(view, V, F)
    assert np.array_equal(d1, d2) and np.isfinite(d1).any()
    kernels = [r._vertex_screen_slot, r._select_slot, r._setup_count_slot, r._bin_fill_slot]
    assert [len(k.signatures) for k in kernels] == [1] * len(kernels)


KEYS = """
import hashlib
from numba.core.serialize import dumps
from softshadows.compare import resolve_methods
from softshadows._jit import KERNELS
resolve_methods("all")
for d in KERNELS:
    f = d.py_func
    if f.__closure__:
        cvars = tuple(c.cell_contents for c in f.__closure__)
        print(f.__module__ + "." + f.__qualname__, hashlib.sha256(dumps(cvars)).hexdigest())
"""


def test_closure_kernels_have_the_same_cache_key_in_every_process():
    # Numba keys a closure kernel's cache entry on its pickled closure variables
    # (numba.core.caching._CacheImpl._index_key). A kernel closing over another dispatcher pickles
    # that dispatcher's per-process random id, so it missed the on-disk cache in every new process
    # and was compiled again on every run (the min-blend tile kernel: ~5 s per penumbra-map run).
    # Two fresh processes must compute the same key for every closure kernel.
    env = dict(os.environ, PYTHONPATH=SRC)
    runs = [
        subprocess.run([sys.executable, "-c", KEYS], env=env, capture_output=True, text=True, check=True).stdout
        for _ in range(2)
    ]
    assert runs[0].strip(), "no closure kernel found: the test checks nothing"
    assert runs[0] == runs[1]


def test_helper_takes_the_slow_frames_then_the_costliest_method_first():
    # the slow-frame methods (softshadows._warm.SLOW_FRAMES) first, so that their frames do not
    # fall at the end of the run; then longest job first (COMPILE_COST): the method with the most
    # compile work, the rest by cost, ties (unknown methods: 5 s) from the list's end
    sys.path.insert(0, SRC)
    from softshadows._warm import COMPILE_COST, SLOW_FRAMES, helper_order

    names = ["hard", "pcss", "irregular", "x-new", "coherent-raytrace", "y-new"]
    order = helper_order(names)
    assert sorted(order) == sorted(names)
    assert SLOW_FRAMES == ("coherent-raytrace",) and order[0] == "coherent-raytrace"
    assert order[1] == max(COMPILE_COST, key=COMPILE_COST.get) == "irregular"
    costs = [COMPILE_COST.get(m, 5.0) for m in order[1:]]
    assert costs == sorted(costs, reverse=True)
    assert order.index("y-new") < order.index("x-new")  # equal cost: from the end of the list
    assert helper_order(["hard", "irregular"]) == ["irregular", "hard"]  # no slow-frame method


def test_helpers_have_no_python_entry_and_raise_instead_of_crashing():
    # inline helpers are compiled without the CPython wrapper (compile time): a call from Python
    # must raise a clear TypeError (Numba alone would jump to a missing entry point and crash), and
    # py_callable must call the same compiled helper
    sys.path.insert(0, SRC)
    import math

    from softshadows import analytic
    from softshadows._jit import py_callable

    with pytest.raises(TypeError, match="kernel helper"):
        analytic.atan2_upper(1.0, 2.0)
    assert abs(py_callable(analytic.atan2_upper)(1.0, 2.0) - math.atan2(1.0, 2.0)) < 1e-15


JIT_MODULE = """
import numpy as np
from numba import prange
from softshadows._jit import kernel

@kernel(inline=True)
def helper(x, k):
    return x * x + k

@kernel
def first(a):
    s = 0.0
    for i in range(a.shape[0]):
        s += helper(a[i], 1.0)
    return s

@kernel
def second(a):
    s = 0.0
    for i in range(a.shape[0]):
        s += helper(a[i], 2.0)
    return s

@kernel(parallel=True)
def par(a, out):
    for i in prange(a.shape[0]):
        out[i] = helper(a[i], 3.0)
"""

JIT_PROBE = """
import sys
import numpy as np
import jitmod
a = np.arange(1000, dtype=np.float64) / 7.0
which = sys.argv[1]
out = np.zeros_like(a)
if which == "first":
    got = jitmod.first(a)
    jitmod.par(a, out)
    assert np.array_equal(out, a * a + 3.0), "parallel kernel"
    assert jitmod.par.stats.cache_misses and not jitmod.par.stats.cache_hits
else:
    got = jitmod.second(a)
ref = float(np.sum(a * a + (1.0 if which == "first" else 2.0)))
assert abs(got - ref) <= 1e-12 * ref, (got, ref)
(res,) = jitmod.helper.overloads.values()
lib = res.library
# the helper has no machine code of its own: the JIT engine never saw its module
assert lib._softshadows_link_only
assert not lib.codegen._engine.is_symbol_defined(res.fndesc.mangled_name)
print(which, "helper from cache" if jitmod.helper.stats.cache_hits else "helper compiled")
"""


def test_link_only_helpers_and_gufuncs_compute_the_same_and_survive_the_cache(tmp_path):
    # softshadows._jit._link_only_helpers: inline helpers and prange gufuncs are finalised without
    # machine code (their callers link their LLVM modules in) and an inline helper is cached as its
    # module alone. A kernel compiled in a later process must link the helper loaded from that
    # cache entry; every result is checked against NumPy.
    import numba

    sys.path.insert(0, SRC)
    from softshadows._jit import _LINK_ONLY_NUMBA, LINK_ONLY

    if not LINK_ONLY:
        pytest.skip(
            f"link-only code generation is off (applied on Numba {sorted(_LINK_ONLY_NUMBA)}, this is "
            f"{numba.__version__}; SOFTSHADOWS_LINK_ONLY={os.environ.get('SOFTSHADOWS_LINK_ONLY', '1')})"
        )
    (tmp_path / "jitmod.py").write_text(JIT_MODULE)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=os.pathsep.join([SRC, str(tmp_path)]))
    outs = [
        subprocess.run([sys.executable, "-c", JIT_PROBE, which], env=env, capture_output=True, text=True).stdout
        for which in ("first", "second")
    ]
    assert outs == ["first helper compiled\n", "second helper from cache\n"], outs
