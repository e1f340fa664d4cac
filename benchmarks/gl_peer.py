"""A CPU peer to measure against: the same ``hard`` frame in OpenGL on Mesa's llvmpipe.

    python benchmarks/gl_peer.py [--scene bunny] [--light rect|sphere] [--size 512] [--map 1024]
                                 [--icosphere LEVEL] [--repeats 15]

llvmpipe is a JIT-compiled, multi-threaded software rasterizer: what a user without a GPU would
otherwise run. The GL frame is the same computation as our ``hard`` at its defaults:

1. a ``--map``^2 depth map from the light centre, with *our* fitted light view
   (``methods.shadowmap.fit_light_view``): linear view depth written to an R32F target under a
   depth test;
2. a ``--size``^2 eye pass over every triangle: per fragment the world position (perspective-
   correct), the face normal turned toward the eye, the Williams test with our constant +
   slope-scaled bias in texels (``shadowmap.receiver_offset``), V written to an R32F target;
3. V read back to the CPU (``glReadPixels`` into NumPy).

Both sides run in this one process, interleaved, after warm-up (JIT compile and the GL shader
compile excluded; geometry is uploaded to the GL once, as our scene keeps its flattened arrays).
Our frame is ``softshadows.render(scene, "hard")``'s total, which also shades the image (the GL
frame does not): the ``V only`` column leaves our shading phase out. The script checks that the
two V agree on all but a fraction of a percent of the pixels both cover (they differ only where a
float32 depth comparison falls the other way) and prints both frame times and their ratio.

``--icosphere LEVEL`` replaces the scene by an icosphere of 20 * 4^LEVEL triangles over a ground
quad (level 8: 1.3 M triangles), the triangle-throughput scene. Needs the optional ``peer`` extra
(``pip install -e '.[peer]'``: moderngl); exits 2 with a clear message when no GL context can be made.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import softshadows as ss
from softshadows.api import eye_view
from softshadows.methods.shadowmap import fit_light_view

VERT_DEPTH = """
#version 330
uniform vec3 o; uniform vec3 R; uniform vec3 U; uniform vec3 F;
uniform vec4 win; uniform vec2 nf;
in vec3 p;
out float zv;
void main() {
    vec3 d = p - o;
    float x = dot(d, R), y = dot(d, U), z = dot(d, F);
    float l = win.x, r = win.y, b = win.z, t = win.w, n = nf.x, f = nf.y;
    gl_Position = vec4((2.0 * x - (r + l) * z) / (r - l), (2.0 * y - (t + b) * z) / (t - b),
                       ((f + n) * z - 2.0 * f * n) / (f - n), z);
    zv = z;
}
"""
FRAG_DEPTH = """
#version 330
in float zv;
out float depth;
void main() { depth = zv; }
"""
VERT_EYE = """
#version 330
uniform vec3 o; uniform vec3 R; uniform vec3 U; uniform vec3 F;
uniform vec4 win; uniform vec2 nf;
in vec3 p; in vec3 nrm;
out vec3 wp; flat out vec3 fn;
void main() {
    vec3 d = p - o;
    float x = dot(d, R), y = dot(d, U), z = dot(d, F);
    float l = win.x, r = win.y, b = win.z, t = win.w, n = nf.x, f = nf.y;
    gl_Position = vec4((2.0 * x - (r + l) * z) / (r - l), (2.0 * y - (t + b) * z) / (t - b),
                       ((f + n) * z - 2.0 * f * n) / (f - n), z);
    wp = p; fn = nrm;
}
"""
FRAG_EYE = """
#version 330
uniform vec3 eye;
uniform vec3 lo; uniform vec3 lR; uniform vec3 lU; uniform vec3 lF;
uniform vec4 lwin; uniform vec2 lsize;
uniform float bias; uniform float slope_bias;
uniform sampler2D smap;
in vec3 wp; flat in vec3 fn;
out float vis;
void main() {
    vec3 n = fn;
    if (dot(n, eye - wp) < 0.0) n = -n;              // normal turned toward the eye
    vec3 d = wp - lo;
    float x = dot(d, lR), y = dot(d, lU), z = dot(d, lF);
    if (!(z > 0.0)) { vis = 1.0; return; }
    float sx = (x / z - lwin.x) / (lwin.y - lwin.x) * lsize.x;
    float sy = (lwin.w - y / z) / (lwin.w - lwin.z) * lsize.y;   // row 0 at the top, as ours
    vec3 L = lo - wp;
    float c = clamp(abs(dot(n, L)) / max(length(L), 1e-30), 1e-3, 1.0);
    float tn = min(sqrt(1.0 - c * c) / c, 10.0);
    float texel = (lwin.y - lwin.x) / lsize.x * z;
    float zt = z - texel * (bias + slope_bias * tn);
    int ci = int(floor(sx)), ri = int(floor(sy));
    if (ri < 0 || ri >= int(lsize.y) || ci < 0 || ci >= int(lsize.x)) { vis = 1.0; return; }
    float stored = texelFetch(smap, ivec2(ci, int(lsize.y) - 1 - ri), 0).r;  // GL rows from the bottom
    vis = (stored < zt) ? 0.0 : 1.0;
}
"""


def icosphere_scene(level: int, light: str) -> ss.Scene:
    """An icosphere of 20 * 4^level triangles over a ground quad, lit from above (trimesh)."""
    import trimesh

    from softshadows.scene.builtin import frame_camera

    sph = trimesh.creation.icosphere(subdivisions=level, radius=0.6)
    verts = np.asarray(sph.vertices) + [0.0, 1.0, 0.0]
    ground = ss.Mesh([[-4, 0, -4], [4, 0, -4], [4, 0, 4], [-4, 0, 4]], [[0, 2, 1], [0, 3, 2]], role="receiver")
    ball = ss.Mesh(verts, np.asarray(sph.faces), albedo=(0.8, 0.3, 0.2), role="occluder")
    rect = ss.RectLight(center=(0.3, 3.0, 0.2), u=(0.8, 0, 0), v=(0, 0, 0.8))
    lt = rect if light == "rect" else ss.SphereLight(center=rect.center, radius=float(np.sqrt(rect.area / np.pi)))
    cam = frame_camera(np.vstack([verts, [[-2.5, 0, -2.5], [2.5, 0, 2.5]]]))
    return ss.Scene([ground, ball], lt, cam, name=f"icosphere-{level}")


def _uniforms(prog, view, prefix=""):
    prog[prefix + "o"].value = tuple(map(float, view.origin))
    prog[prefix + "R"].value = tuple(map(float, view.right))
    prog[prefix + "U"].value = tuple(map(float, view.up))
    prog[prefix + "F"].value = tuple(map(float, view.forward))
    prog[prefix + "win"].value = tuple(map(float, view.window))


class GLHard:
    """The ``hard`` frame in OpenGL (see the module docstring)."""

    def __init__(self, scene, size: int, map_size: int, bias: float, slope_bias: float):
        import moderngl

        self.ctx = moderngl.create_standalone_context(backend="egl")
        self.renderer = self.ctx.info.get("GL_RENDERER", "?")
        flat = scene.flat
        ctx = self.ctx
        self.view = eye_view(scene, size, size)
        self.lview = fit_light_view(scene, map_size)
        tri = flat.vertices[flat.faces]  # (F,3,3) non-indexed: a flat face normal per vertex
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        occ = tri[flat.occluder]
        self.p_depth = ctx.program(vertex_shader=VERT_DEPTH, fragment_shader=FRAG_DEPTH)
        self.p_eye = ctx.program(vertex_shader=VERT_EYE, fragment_shader=FRAG_EYE)
        vbo_occ = ctx.buffer(occ.astype("f4").tobytes())
        self.vao_depth = ctx.vertex_array(self.p_depth, [(vbo_occ, "3f", "p")])
        inter = np.concatenate([tri, np.repeat(fn[:, None, :], 3, axis=1)], axis=2).astype("f4")
        self.vbo_eye = ctx.buffer(inter.tobytes())
        self.vao_eye = ctx.vertex_array(self.p_eye, [(self.vbo_eye, "3f 3f", "p", "nrm")])
        self.tex_map = ctx.texture((map_size, map_size), 1, dtype="f4")
        self.tex_map.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.fbo_map = ctx.framebuffer([self.tex_map], ctx.depth_renderbuffer((map_size, map_size)))
        self.rb_v = ctx.renderbuffer((size, size), 1, dtype="f4")
        self.fbo_eye = ctx.framebuffer([self.rb_v], ctx.depth_renderbuffer((size, size)))
        lv, ev = self.lview, self.view
        _uniforms(self.p_depth, lv)
        self.p_depth["nf"].value = (float(lv.near), float(lv.far))
        _uniforms(self.p_eye, ev)
        self.p_eye["nf"].value = (float(ev.near), float(ev.far))
        for k, v in (("lo", lv.origin), ("lR", lv.right), ("lU", lv.up), ("lF", lv.forward)):
            self.p_eye[k].value = tuple(map(float, v))
        self.p_eye["lwin"].value = tuple(map(float, lv.window))
        self.p_eye["lsize"].value = (float(map_size), float(map_size))
        self.p_eye["eye"].value = tuple(map(float, scene.camera.eye))
        self.p_eye["bias"].value = float(bias)
        self.p_eye["slope_bias"].value = float(slope_bias)
        self.p_eye["smap"].value = 0
        self.size = size
        self.moderngl = moderngl

    def frame(self) -> np.ndarray:
        ctx, mgl = self.ctx, self.moderngl
        ctx.enable(mgl.DEPTH_TEST)
        self.fbo_map.use()
        self.fbo_map.clear(3.0e38, 0.0, 0.0, 0.0, depth=1.0)
        self.vao_depth.render(mgl.TRIANGLES)
        self.fbo_eye.use()
        self.fbo_eye.clear(-1.0, 0.0, 0.0, 0.0, depth=1.0)
        self.tex_map.use(0)
        self.vao_eye.render(mgl.TRIANGLES)
        raw = self.fbo_eye.read(components=1, dtype="f4")
        v = np.frombuffer(raw, np.float32).reshape(self.size, self.size)[::-1]  # GL rows from the bottom
        return np.where(v < 0.0, np.float32(np.nan), v)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--map", type=int, default=1024)
    ap.add_argument("--icosphere", type=int, default=None, help="icosphere subdivision level instead of --scene")
    ap.add_argument("--repeats", type=int, default=15)
    a = ap.parse_args(argv)
    try:
        import moderngl  # noqa: F401
    except ImportError:
        print("gl_peer: moderngl is not installed (pip install -e '.[peer]')", file=sys.stderr)
        return 2
    scene = icosphere_scene(a.icosphere, a.light) if a.icosphere is not None else ss.load_scene(a.scene, a.light)
    hard = ss.methods()["hard"]
    p = {q.name: q.default for q in hard.params}
    try:
        gl = GLHard(scene, a.size, a.map, p["bias"], p["slope_bias"])
    except Exception as exc:  # no EGL / no GL 3.3 context on this machine
        print(f"gl_peer: cannot create an OpenGL context: {exc}", file=sys.stderr)
        return 2
    ntri = len(scene.flat.faces)
    print(f"{scene.name} ({a.light} light), {ntri} triangles, eye {a.size}^2, map {a.map}^2; GL: {gl.renderer}")
    ours = ss.render(scene, "hard", a.size, a.size, map_size=a.map)
    v_gl = gl.frame()
    both = ~np.isnan(ours.visibility) & ~np.isnan(v_gl)
    disagree = float(np.mean(ours.visibility[both] != v_gl[both])) if both.any() else float("nan")
    cover = float(np.mean(np.isnan(ours.visibility) != np.isnan(v_gl)))
    t_ours, t_ours_v, t_gl = [], [], []
    for _ in range(a.repeats):  # interleaved
        r = ss.render(scene, "hard", a.size, a.size, map_size=a.map)
        t_ours.append(r.timings["total"])
        t_ours_v.append(r.timings["total"] - r.timings.get("shading", 0.0))
        t0 = time.perf_counter()
        gl.frame()
        t_gl.append(time.perf_counter() - t0)
    mo, mv, mg = (float(np.median(t)) * 1e3 for t in (t_ours, t_ours_v, t_gl))
    print(
        f"V agreement: {100 * (1 - disagree):.3f}% of {int(both.sum())} pixels both cover; coverage differs on {100 * cover:.3f}%"
    )
    print(f"| frame | ms (median of {a.repeats}) | x ours |")
    print("|---|---|---|")
    print(f"| ours (`hard`, full frame) | {mo:.1f} | 1.00 |")
    print(f"| ours, V only (no shading) | {mv:.1f} | {mv / mo:.2f} |")
    print(f"| OpenGL on llvmpipe | {mg:.1f} | {mg / mo:.2f} |")
    print(f"llvmpipe / ours = {mg / mo:.2f} (>1: ours is faster)")
    if not (disagree < 0.005 and cover < 0.005):
        print("gl_peer: the two V disagree on more than 0.5% of pixels", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    sys.exit(main())
