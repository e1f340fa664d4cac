"""A CPU peer to measure against: the ``hard`` frame in OpenGL on Mesa's llvmpipe (issues 15, 16).

llvmpipe is a JIT-compiled, multi-threaded software rasterizer: what a user without a GPU would
otherwise run. :class:`GLHard` renders the same computation as our ``hard`` at its defaults, through
``moderngl`` (the optional ``peer`` extra: ``pip install -e '.[peer]'``; imported lazily) on a
headless EGL context:

1. a ``map_size``^2 depth map from the light centre, with *our* fitted light view
   (``methods.shadowmap.fit_light_view``): linear view depth written to an R32F target under a
   depth test;
2. the eye pass over every triangle: per fragment the world position (perspective-correct), the
   face normal turned toward the eye, the Williams test with our constant + slope-scaled bias in
   texels (``shadowmap.receiver_offset``), V written to an R32F target;
3. V read back to the CPU (``glReadPixels`` into NumPy).

Geometry is uploaded once (as our scene keeps its flattened arrays). The two V differ only where a
float32 depth comparison falls the other way: :func:`agreement` measures it. Used by
``benchmarks/gl_peer.py`` and ``softshadows bench icosphere --sweep triangles`` (the llvmpipe column).
"""

from __future__ import annotations

import numpy as np

from .api import eye_view
from .methods.shadowmap import fit_light_view

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


def _uniforms(prog, view, prefix=""):
    prog[prefix + "o"].value = tuple(map(float, view.origin))
    prog[prefix + "R"].value = tuple(map(float, view.right))
    prog[prefix + "U"].value = tuple(map(float, view.up))
    prog[prefix + "F"].value = tuple(map(float, view.forward))
    prog[prefix + "win"].value = tuple(map(float, view.window))


class GLHard:
    """The ``hard`` frame of ``scene`` in OpenGL (see the module docstring); :meth:`frame` renders it
    and returns V (H,W) float32, NaN where no surface. Raises where no GL context can be made."""

    def __init__(self, scene, width: int, height: int, map_size: int, bias: float, slope_bias: float):
        import moderngl

        self.ctx = moderngl.create_standalone_context(backend="egl")
        self.renderer = self.ctx.info.get("GL_RENDERER", "?")
        flat = scene.flat
        ctx = self.ctx
        self.view = eye_view(scene, width, height)
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
        self.rb_v = ctx.renderbuffer((width, height), 1, dtype="f4")
        self.fbo_eye = ctx.framebuffer([self.rb_v], ctx.depth_renderbuffer((width, height)))
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
        self.width, self.height = width, height
        self.moderngl = moderngl

    def release(self) -> None:
        """Free the GL context and its objects."""
        self.ctx.release()

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
        v = np.frombuffer(raw, np.float32).reshape(self.height, self.width)[::-1]  # GL rows from the bottom
        return np.where(v < 0.0, np.float32(np.nan), v)


def unavailable() -> str | None:
    """None where moderngl can be imported, else a one-line reason (the peer is optional)."""
    try:
        import moderngl  # noqa: F401
    except ImportError:
        return "moderngl is not installed (pip install -e '.[peer]')"
    return None


def make_peer(scene, width: int, height: int, map_size: int, bias: float, slope_bias: float):
    """(GLHard, None) or (None, a one-line reason) where moderngl or a GL 3.3 context is missing."""
    why = unavailable()
    if why is not None:
        return None, why
    try:
        return GLHard(scene, width, height, map_size, bias, slope_bias), None
    except Exception as exc:  # no EGL / no GL 3.3 context on this machine
        return None, f"cannot create an OpenGL context: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"


def hard_defaults() -> dict:
    """``hard``'s default parameters (the peer renders ``hard`` at its defaults)."""
    from .methods import get_method

    return {q.name: q.default for q in get_method("hard").params}


def agreement(v_ours: np.ndarray, v_gl: np.ndarray) -> tuple[float, float, int]:
    """(fraction of the pixels both cover where V differs, fraction where the coverage differs, the
    number of pixels both cover)."""
    both = ~np.isnan(v_ours) & ~np.isnan(v_gl)
    n = int(both.sum())
    disagree = float(np.mean(v_ours[both] != v_gl[both])) if n else float("nan")
    cover = float(np.mean(np.isnan(v_ours) != np.isnan(v_gl)))
    return disagree, cover, n
