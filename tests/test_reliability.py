"""Reliability (issue 12): one test per class of failure, and a bounded fuzz test.

1. georeferenced and tiny scenes give the same V as at the origin (every method);
2. awkward light positions: no traceback, and the right answer or a warning naming the limit;
3. outputs checked before rendering and written atomically;
4. every argument validated at the boundary (API and CLI);
5. files people really have (Latin-1 OBJ/MTL, TOML with a BOM, glTF with a missing buffer);
6. render() from several threads with the thread-unsafe ``workqueue`` Numba layer;
7. silent no-ops are said (one warning).
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

import softshadows as ss
from softshadows.cli import main
from softshadows.scene import primitives as prim
from softshadows.scene.types import Camera, Mesh, RectLight, Scene, SphereLight

SRC = str(Path(__file__).resolve().parents[1] / "src")
W, H = 48, 36


def _moved(sc: Scene, offset, k: float = 1.0) -> Scene:
    """The same scene scaled by ``k`` about the origin and moved by ``offset`` (float64)."""
    off = np.asarray(offset, np.float64)
    ms = [Mesh(m.vertices * k + off, m.faces, m.albedo, m.role, m.name) for m in sc.meshes]
    L = sc.light
    if L.shape == "rect":
        lt = RectLight(L.center * k + off, L.u * k, L.v * k, L.intensity)
    else:
        lt = SphereLight(L.center * k + off, L.radius * k, L.intensity)
    c = sc.camera
    return Scene(ms, lt, Camera(c.eye * k + off, c.target * k + off, c.up, c.fov_y), sc.name)


# small maps and few samples: these tests compare a method with itself (or check a warning), so
# the defaults' resolution buys nothing but time
SMALL = {
    "ground-truth": {"samples": 16},
    "hard": {"map_size": 256},
    "pcss": {"map_size": 256},
    "penumbra-map": {"map_size": 256},
    "soft-shadow-map": {"map_size": 64, "ssm_size": 64},
    "occlusion-textures": {"texture_size": 128, "slices": 8},
}


def _kw(method):
    return SMALL.get(method, {})


def _cases():
    for light in ("rect", "sphere"):
        for name, m in ss.methods().items():
            if light in m.light_shapes:
                yield light, name


# ---- 1. georeferenced and tiny scenes ---------------------------------------------------------------
@pytest.mark.parametrize("light, method", list(_cases()))
def test_far_and_tiny_scenes_give_the_same_v(light, method):
    base = ss.load_scene("square", light=light)
    ref = ss.render(base, method, W, H, seed=3, **_kw(method))
    for offset, k in (((3e7, -1e7, 5e6), 1.0), ((2e5, 0.0, 1e5), 1e-6)):
        moved = _moved(base, offset, k)
        res = ss.render(moved, method, W, H, seed=3, **_kw(method))
        v0, v = ref.visibility, res.visibility
        # same pixels covered: the recentred scene differs from the original only by float64
        # rounding, far below a pixel
        assert np.array_equal(np.isfinite(v0), np.isfinite(v)), (offset, k)
        m = np.isfinite(v0)
        d = np.abs(v0[m] - v[m])
        # V identical up to texel/pixel-edge flips caused by that rounding (before the fix: MAE
        # 0.1-1 at 1e7 units, every pixel lost at extent 1e-6)
        assert d.mean() < 2e-3 and (d > 0.05).mean() < 0.01, (offset, k, d.mean())
        # positions are given back in the user's coordinates (float64: the offset is kept exactly)
        p_expected = ref.position[m].astype(np.float64) * k + np.asarray(offset)
        # tolerance: float32 positions of the original (1e-6 of the extent) plus float64 rounding
        # of the offset (a few ulps of |offset|)
        tol = 1e-5 * k + 8 * np.finfo(np.float64).eps * float(np.max(np.abs(offset)))
        assert np.allclose(res.position[m], p_expected, rtol=0, atol=tol)


# ---- 2. the light in awkward places --------------------------------------------------------------
def _box_scene(light) -> Scene:
    gv, gf = prim.plane(6, 6, 1, 1, y=0.0, center=(0, 0, 0))
    bv, bf = prim.box(np.array([1.0, 1.0, 1.0]), np.array([0.0, 1.0, 0.0]))
    cam = Camera((3, 4, 5), (0, 0.5, 0), (0, 1, 0), 45)
    meshes = [Mesh(gv, gf, 0.8, "receiver", "ground"), Mesh(bv, bf, 0.8, "occluder", "box")]
    return Scene(meshes, light, cam, "box")


AWKWARD = {
    "rect inside a closed box": RectLight((0, 1.0, 0), (0.3, 0, 0), (0, 0, 0.3)),
    "sphere at the occluders' centre": SphereLight((0, 1.0, 0), 0.2),
    "rect touching the box top": RectLight((0, 1.5, 0), (0.3, 0, 0), (0, 0, 0.3)),
}


@pytest.mark.parametrize("case", list(AWKWARD))
def test_awkward_lights_right_or_warned(case):
    sc = _box_scene(AWKWARD[case])
    gt = ss.render(sc, "ground-truth", W, H, samples=16).visibility
    v_gt = float(np.nanmean(gt))
    assert v_gt < 0.02  # the box hides the light from every receiver point (sanity of the case)
    for name, m in ss.methods().items():
        if name == "ground-truth" or sc.light.shape not in m.light_shapes:
            continue
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            v = ss.render(sc, name, W, H, **_kw(name)).visibility  # before: ValueError (sphere at the centre)
        msgs = [str(w.message) for w in rec]
        right = abs(float(np.nanmean(v)) - v_gt) < 0.05
        warned = any(msg.startswith(f"{name}:") and "light's centre" in msg for msg in msgs)
        assert right or warned, (case, name, float(np.nanmean(v)), msgs)


def test_light_facing_away_warns_and_does_not_fail():
    sc = _box_scene(RectLight((0, 3.0, 0), (0.3, 0, 0), (0, 0, -0.3)))  # emits upward, away from everything
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        res = ss.render(sc, "hard", W, H)
    assert [str(w.message) for w in rec if "reaches no surface" in str(w.message)]
    m = np.isfinite(res.visibility)
    albedo_ambient = 0.8 * 0.04  # every visible surface: albedo x ambient only
    assert np.allclose(res.image[m], albedo_ambient, atol=1e-6)


# ---- 3. outputs checked first, written atomically ---------------------------------------------------
def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("softshadows: warning:")]
    assert len(lines) == 1 and lines[0].startswith("softshadows: error: "), err
    return lines[0]


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["-o", "{d}"], "is a folder"),
        (["-o", "{d}/a.jpg"], ".png"),
        (["-o", "{d}/a.png", "--exr", "{d}/a.png"], ".exr"),
        (["-o", "{d}/a.png", "--v-png", "{d}/sub/../a.png"], "same file"),
        (["-o", "{d}/afile/x.png"], "not a folder"),
    ],
)
def test_outputs_checked_before_rendering(tmp_path, capsys, monkeypatch, extra, needle):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "sub").mkdir()
    import softshadows.api as api

    def no_render(*a, **k):  # validation must happen before any rendering
        raise AssertionError("rendered before the outputs were checked")

    monkeypatch.setattr(api, "_render", no_render)
    args = ["render", "square", "-m", "hard", "--size", "16x12", "-q"] + [a.format(d=tmp_path) for a in extra]
    assert main(args) == 2
    assert needle in _one_error_line(capsys.readouterr().err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "sub"]


def test_failing_later_output_leaves_nothing_behind(tmp_path, capsys, monkeypatch):
    import softshadows.shading as shading

    def full_disk(path, channels):
        with open(path, "wb") as fh:
            fh.write(b"\x76\x2f\x31\x01partial")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(shading, "save_exr", full_disk)
    out, exr = tmp_path / "a.png", tmp_path / "a.exr"
    assert main(["render", "square", "-m", "hard", "--size", "16x12", "-q", "-o", str(out), "--exr", str(exr)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert line == f"softshadows: error: cannot write {exr}: No space left on device"
    assert list(tmp_path.iterdir()) == []  # no orphaned PNG, no truncated EXR, no temp file


def test_atomic_outputs_have_the_usual_mode(tmp_path):
    from softshadows.io import write_text

    write_text(tmp_path / "a.json", "{}")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o666 & ~umask  # as open() would give


def test_atomic_write_keeps_old_file_on_failure_and_file_size_limit(tmp_path):
    # a real file-size limit (RLIMIT_FSIZE) in a child process: the write fails with EFBIG
    target = tmp_path / "v.exr"
    target.write_bytes(b"old")
    code = textwrap.dedent(f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_FSIZE, (2000, 2000))
        sys.path.insert(0, {SRC!r})
        import numpy as np
        from softshadows.shading import save_exr
        from softshadows.io import OutputError
        try:
            save_exr({str(target)!r}, {{"V": np.random.default_rng(0).random((64, 64), dtype=np.float32)}})
        except OutputError as exc:
            print(exc)
            sys.exit(2)
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, p.stderr
    assert p.stdout.startswith(f"cannot write {target}: "), p.stdout
    assert target.read_bytes() == b"old" and [x.name for x in tmp_path.iterdir()] == ["v.exr"]


def test_cli_file_size_limit_one_line_nothing_left(tmp_path):
    # the whole command under a real file-size limit: one line naming the user's path, exit 2
    code = textwrap.dedent(f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_FSIZE, (1500, 1500))
        sys.path.insert(0, {SRC!r})
        from softshadows.cli import main
        sys.exit(main(["render", "square", "-m", "hard", "--set", "map_size=256", "--size", "64x48", "-q",
                       "-o", {str(tmp_path / "a.png")!r}, "--exr", {str(tmp_path / "a.exr")!r}]))
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, p.stderr[-2000:]
    line = _one_error_line(p.stderr)
    assert line.startswith(f"softshadows: error: cannot write {tmp_path}/a.") and "File too large" in line, line
    assert list(tmp_path.iterdir()) == []


def test_a_cache_that_cannot_be_written_does_not_fail_the_run(tmp_path):
    # a cold JIT cache under a file-size limit: the kernel runs as compiled, one warning; before,
    # Numba's EFBIG ended the command with "File too large" (the test above, on a cold cache)
    # a kernel of a module named like the package's (the guard leaves other Numba code alone), and one
    # of another module, which still raises
    src = "from numba import njit\n\n@njit(cache=True)\ndef f(x):\n    return x + 1\n"
    (tmp_path / "softshadows_kmod.py").write_text(src)
    (tmp_path / "othermod.py").write_text(src)
    code = textwrap.dedent(f"""
        import resource, sys, warnings
        sys.path[:0] = [{SRC!r}, {str(tmp_path)!r}]
        import softshadows._jit
        import softshadows_kmod, othermod
        resource.setrlimit(resource.RLIMIT_FSIZE, (64, 64))
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            print(softshadows_kmod.f(1), softshadows_kmod.f(2.5))
        print(len(w), w[0].message if w else "")
        try:
            othermod.f(1)
        except OSError as exc:
            print("other:", exc.strerror)
    """)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert p.returncode == 0, p.stderr[-2000:]
    first, second, third = p.stdout.splitlines()
    assert first == "2 3.5"
    assert second.startswith("1 the compiled kernels could not be cached (File too large)"), second
    assert third == "other: File too large"


def test_bench_and_compare_outputs_checked_first(tmp_path, capsys):
    (tmp_path / "f").write_text("x")
    assert main(["bench", "square", "--methods", "hard", "--sizes", "16", "--json", str(tmp_path), "-q"]) == 2
    assert "is a folder" in _one_error_line(capsys.readouterr().err)
    assert main(["compare", "square", "--methods", "hard", "--size", "16x12", "-o", str(tmp_path / "f"), "-q"]) == 2
    assert "not a folder" in _one_error_line(capsys.readouterr().err)


# ---- 4. arguments validated at the boundary --------------------------------------------------------
@pytest.mark.parametrize(
    "call, needle",
    [
        (lambda sc: ss.render(None, "hard", 16, 12), "scene must be a softshadows.Scene"),
        (lambda sc: ss.render("square", "hard", 16, 12), "load_scene('square')"),
        (lambda sc: ss.render(sc, "hard", 16, 12, seed=2**70), "seed"),
        (lambda sc: ss.render(sc, "hard", 16, 12, seed=-1), "seed"),
        (lambda sc: ss.render(sc, "hard", 16, 12, seed=1.5), "seed"),
        (lambda sc: ss.render(sc, "hard", 16, 12, seed=True), "seed"),
        (lambda sc: ss.render(sc, "hard", True, 12), "width"),
        (lambda sc: ss.render(sc, None, 16, 12), "method"),
        (lambda sc: ss.render(sc, "hard", 16, 12, map_size=True), "map_size"),
        (lambda sc: ss.load_scene(None), "scene must be a name or a file path"),
        (lambda sc: ss.load_scene("square", light="disk"), "light"),
        (lambda sc: Scene("x", sc.light, sc.camera), "meshes"),
        (lambda sc: Scene(sc.meshes, sc.light, "cam"), "camera"),
        (lambda sc: Camera((0, 0, 5), (0, 0, 0), fov_y="45"), "camera.fov_y"),
        (lambda sc: Camera((0, 0, 5), (0, 0, 0), fov_y=179), "camera.fov_y"),
        (lambda sc: SphereLight((0, 1, 0), "1"), "light.radius"),
        (lambda sc: RectLight((0, 1, 0), (1, 0, 0), (0, 0, 1), intensity=None), "light.intensity"),
        (lambda sc: RectLight("abc", (1, 0, 0), (0, 0, 1)), "light.center"),
        (lambda sc: Mesh("abc", [[0, 1, 2]]), "vertices"),
        (lambda sc: Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], albedo="red"), "albedo"),
        (lambda sc: Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], role=None), "role"),
    ],
)
def test_api_arguments_validated(call, needle):
    sc = ss.load_scene("square")
    with pytest.raises(ss.SoftShadowsError) as ei:
        call(sc)
    assert needle in str(ei.value) and "\n" not in str(ei.value)


def test_image_too_large_for_memory_refused_up_front(monkeypatch):
    import softshadows.api as api

    monkeypatch.setattr(api, "available_memory", lambda: 2**30)  # 1 GiB available
    with pytest.raises(ss.SoftShadowsError, match=r"needs about \d+\.\d GiB"):
        ss.render(ss.load_scene("square"), "hard", 8192, 8192)


def test_fov_y_one_rule_in_loader_and_camera(tmp_path):
    for fov in (179, 0, -3):
        f = tmp_path / "s.toml"
        f.write_text(f'[camera]\neye = [0, 2, 5]\ntarget = [0, 0, 0]\nfov_y = {fov}\n[[mesh]]\nprimitive = "box"\n')
        with pytest.raises(ss.SceneError, match=r"\[camera\]\.fov_y must be a number of degrees in \(0, 179\)"):
            ss.load_scene(f)
        with pytest.raises(ss.SceneError, match=r"camera\.fov_y must be a number of degrees in \(0, 179\)"):
            Camera((0, 2, 5), (0, 0, 0), fov_y=fov)


def test_cli_huge_seed_one_line(capsys):
    assert main(["render", "square", "-m", "hard", "--size", "16x12", "--seed", str(2**70), "-q"]) == 2
    assert "seed" in _one_error_line(capsys.readouterr().err)


# ---- 5. files people really have ------------------------------------------------------------------
def test_latin1_obj_bom_toml_and_missing_gltf_buffer(tmp_path):
    (tmp_path / "m.mtl").write_bytes(b"# mat\xe9riau de Jos\xe9\nnewmtl a\nKd 0.5 0.5 0.5\n")
    obj = b"# cr\xe9\xe9 par Jos\xe9\nmtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nusemtl a\nf 1 2 3\nf 1 2 4\n"
    (tmp_path / "lat.obj").write_bytes(obj)
    sc = ss.load_scene(tmp_path / "lat.obj")
    assert len(sc.meshes[1].faces) == 2
    toml = '\ufeffname = "bom"\n[[mesh]]\nprimitive = "box"\n'
    (tmp_path / "bom.toml").write_bytes(toml.encode("utf-8"))
    assert ss.load_scene(tmp_path / "bom.toml").name == "bom"
    gltf = (
        '{"asset": {"version": "2.0"}, "buffers": [{"uri": "gone.bin", "byteLength": 36}], '
        '"bufferViews": [{"buffer": 0, "byteLength": 36}], "accessors": [{"bufferView": 0, '
        '"componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}], '
        '"meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "nodes": [{"mesh": 0}], '
        '"scenes": [{"nodes": [0]}], "scene": 0}'
    )
    (tmp_path / "m.gltf").write_text(gltf)
    with pytest.raises(ss.SceneError, match=r"gone\.bin"):
        ss.load_scene(tmp_path / "m.gltf")


# ---- 6. concurrency --------------------------------------------------------------------------------
def test_render_from_threads_with_workqueue_layer():
    code = textwrap.dedent(f"""
        import sys, threading
        sys.path.insert(0, {SRC!r})
        import numpy as np, numba, softshadows as ss
        sc = ss.load_scene("square")
        out = {{}}
        def go(i):
            out[i] = ss.render(sc, "pcss", 40, 30, seed=1).visibility
        ts = [threading.Thread(target=go, args=(i,)) for i in range(3)]
        [t.start() for t in ts]
        [t.join() for t in ts]
        alone = ss.render(sc, "pcss", 40, 30, seed=1).visibility
        assert numba.threading_layer() == "workqueue"
        print(len(out), all(np.array_equal(out[i], alone, equal_nan=True) for i in out))
    """)
    env = dict(os.environ, NUMBA_THREADING_LAYER="workqueue")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    # before: the workqueue layer aborts the process ("not threadsafe ... concurrent access")
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.strip() == "3 True"


# ---- 7. silent no-ops are said -----------------------------------------------------------------------
def test_no_receivers_warns_once_for_soft_shadow_map():
    sc = ss.load_scene("square")
    only_occluders = Scene(
        [Mesh(m.vertices, m.faces, m.albedo, "occluder", m.name) for m in sc.meshes], sc.light, sc.camera
    )
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        res = ss.render(only_occluders, "soft-shadow-map", W, H)
    msgs = [str(w.message) for w in rec if "no receiver faces" in str(w.message)]
    assert len(msgs) == 1 and msgs[0].startswith("soft-shadow-map:")
    assert np.nanmin(res.visibility) == 1.0  # what the warning says: V = 1 everywhere


# ---- fuzz: randomly broken scene files and meshes --------------------------------------------------
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

TEMPLATE = {
    "name": '"fuzz"',
    "camera.eye": "[0, 3, 6]",
    "camera.target": "[0, 0.5, 0]",
    "camera.fov_y": "45",
    "light.center": "[0.3, 3, 0.2]",
    "light.u": "[0.6, 0, 0]",
    "light.v": "[0, 0, 0.6]",
    "light.intensity": "1",
    "mesh0.primitive": '"box"',
    "mesh0.size": "[1, 1, 1]",
    "mesh0.center": "[0, 0.6, 0]",
    "mesh0.role": '"occluder"',
    "mesh1.primitive": '"plane"',
    "mesh1.size": "6",
    "mesh1.role": '"receiver"',
}
EXTRA_KEYS = ["mesh0.radius", "light.radius", "light.type", "mesh1.cells", "mesh0.translate", "mesh1.scale", "wat"]
JUNK = st.sampled_from(
    [
        "0",
        "-1",
        "1e308",
        "-1e-300",
        "nan",
        "inf",
        "true",
        '"x"',
        "[]",
        "[1, 2]",
        "[0, 0, 0]",
        "[1e300, 0, 0]",
        "[nan, 0, 0]",
        "[[1]]",
        "{}",
        '"sphere"',
        '"both"',
        "179",
        "1e-9",
        "[1e-9, 1e-9, 1e-9]",
        "[1e8, 1e8, 1e8]",
        "[3e6, 0, -2e6]",
        "[0, 0.6, 0]",
        "[0, 0.1, 0]",
    ]
)


def _toml(fields: dict) -> str:
    top = [f"{k} = {v}" for k, v in fields.items() if "." not in k]
    out = top[:]
    for table in ("camera", "light"):
        keys = {k.split(".", 1)[1]: v for k, v in fields.items() if k.startswith(table + ".")}
        if keys:
            out.append(f"[{table}]")
            out += [f"{k} = {v}" for k, v in keys.items()]
    for i in range(2):
        keys = {k.split(".", 1)[1]: v for k, v in fields.items() if k.startswith(f"mesh{i}.")}
        out.append("[[mesh]]")
        out += [f"{k} = {v}" for k, v in keys.items()]
    return "\n".join(out) + "\n"


@st.composite
def broken_scene_file(draw):
    if draw(st.booleans()):  # a TOML scene with some fields broken, dropped or added
        fields = dict(TEMPLATE)
        for k in draw(st.lists(st.sampled_from(sorted(TEMPLATE)), max_size=4)):
            if draw(st.booleans()):
                fields[k] = draw(JUNK)
            else:
                fields.pop(k, None)
        if draw(st.booleans()):
            fields[draw(st.sampled_from(EXTRA_KEYS))] = draw(JUNK)
        text = _toml(fields).encode()
        return "scene.toml", _mangle(draw, text)
    # an OBJ mesh: random (possibly non-finite, huge or tiny) vertices, faces possibly out of range
    n = draw(st.integers(0, 6))
    num = st.one_of(st.floats(-10, 10), st.sampled_from([0.0, 1e-12, 1e12, float("nan"), float("inf")]))
    lines = ["# fuzz caf\xe9"] + [f"v {draw(num)} {draw(num)} {draw(num)}" for _ in range(n)]
    for _ in range(draw(st.integers(0, 4))):
        lines.append("f " + " ".join(str(draw(st.integers(-2, n + 1))) for _ in range(draw(st.integers(2, 4)))))
    text = "\n".join(lines).encode("latin-1")
    return "mesh.obj", _mangle(draw, text)


def _mangle(draw, text: bytes) -> bytes:
    how = draw(st.sampled_from(["keep", "keep", "truncate", "flip"]))
    if how == "truncate" and text:
        return text[: draw(st.integers(0, len(text) - 1))]
    if how == "flip" and text:
        i = draw(st.integers(0, len(text) - 1))
        return text[:i] + bytes([draw(st.integers(0, 255))]) + text[i + 1 :]
    return text


@settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    case=broken_scene_file(),
    method=st.sampled_from(["hard", "pcss", "penumbra-map", "soft-shadow-map", "occlusion-textures", "ground-truth"]),
    light=st.sampled_from([None, "rect", "sphere"]),
)
def test_fuzz_broken_scene_files_exit_0_or_one_line(tmp_path_factory, capsys, case, method, light):
    d = tmp_path_factory.mktemp("fuzz")
    name, data = case
    (d / name).write_bytes(data)
    exr = d / "out.exr"
    args = ["render", str(d / name), "-m", method, "--size", "24x18", "-o", str(d / "o.png"), "--exr", str(exr), "-q"]
    if method == "ground-truth":
        args += ["--set", "samples=4"]
    if light:
        args += ["--light", light]
    code = main(args)  # any exception here (a traceback) fails the test
    err = capsys.readouterr().err
    assert code in (0, 2), (code, err)
    if code == 2:
        _one_error_line(err)
        assert not exr.exists()
    else:
        from softshadows.shading import load_exr

        v = load_exr(exr)["V"]
        m = ~np.isnan(v)
        assert np.all(np.isfinite(v[m])) and np.all((v[m] >= 0) & (v[m] <= 1))
