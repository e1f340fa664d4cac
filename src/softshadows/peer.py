"""A CPU peer to measure against: our ``hard`` and ``pcss`` frames in OpenGL on Mesa's llvmpipe
(issues 15, 16).

llvmpipe is a JIT-compiled, multi-threaded software rasterizer: what a user without a GPU would
otherwise run. Through ``moderngl`` (the optional ``peer`` extra: ``pip install -e '.[peer]'``;
imported lazily) on a headless EGL context, :class:`GLHard` renders the same computation as our
``hard`` at its defaults and :class:`GLPCSS` the same as our ``pcss`` at its defaults. Both share
(:class:`GLFrame`):

1. a ``map_size``^2 depth map from the light centre, with *our* fitted light view
   (``methods.shadowmap.fit_light_view``): linear view depth written to an R32F target under a
   depth test;
2. the eye pass over every triangle: per fragment the world position (perspective-correct), the
   face normal turned toward the eye, the point in the map's texel coordinates and its light view
   depth, our constant + slope-scaled bias in texels (``shadowmap.receiver_offset``), then the
   method's shadow test, V written to an R32F target. ``hard`` runs its one-texel test per
   fragment (forward); ``pcss`` has the triangles write a G-buffer (position, normal) and runs
   its taps once per pixel in a full-screen pass (deferred: no taps for overdrawn fragments; the
   same V bit for bit, 1.4-1.6x faster on bunny; deferred ``hard`` was slower);
3. V read back to the CPU (``glReadPixels`` into NumPy).

With ``shade`` the eye pass also shades, as our frame does after V (``shading.shade``: albedo x
(unshadowed direct light from the light centre x V + ambient), the face's albedo a vertex
attribute), and :attr:`GLFrame.image` holds the image after each frame: ``"float"`` writes our
float32 colour (an RGBA32F target with V in its alpha: one target, one clear, one read; V in a
target of its own was slower), ``"rgba8"`` an 8-bit colour (clamped to [0, 1]) beside V: what a
display takes, less than ours keeps, and llvmpipe's faster target. Either is a like-for-like peer
of our whole frame (``benchmarks/gl_peer.py``).

``hard``'s test is Williams's (one texel). ``pcss``'s is Fernando's three steps as our
``methods/pcss.py`` computes them at its defaults (``docs/methods/pcss.md``), with *our* tap
patterns (``pcss.sample_pattern``, uploaded as uniforms): a blocker search of the map region the
light subtends at the map's nearest depth (which a two-pass min reduction of the map finds on the
GL side before the eye pass), the average blocker depth, the parallel-plane penumbra width, PCF
over that width with a bilinearly weighted 2x2 comparison per tap; every tap compares against the
receiver's tangent plane (our ``receiver_plane``). Our work-skipping shortcuts (empty regions of
the map, plane depths not needed) change no V; the GL pass has only the coarsest, equally exact
one: a search region entirely off the map is lit without taking its taps.

Geometry is uploaded once (as our scene keeps its flattened arrays). The GL computes in float32
(ours in float64 on float32 maps): ``hard``'s V differ only where a depth comparison falls the
other way (:func:`agreement`); ``pcss``'s also where a tap's texel or a blocker changes, which moves
the penumbra width a little (:func:`agreement` with a tolerance, :func:`dv_stats`). Used by
``benchmarks/gl_peer.py`` and ``softshadows bench icosphere --sweep triangles`` (the llvmpipe column).
"""

from __future__ import annotations

import numpy as np

from .api import eye_view
from .methods.shadowmap import fit_light_view

# the perspective projection of a view (origin o, axes R U F, window, near/far) to clip space
_PROJECT = """
uniform vec3 o; uniform vec3 R; uniform vec3 U; uniform vec3 F;
uniform vec4 win; uniform vec2 nf;
vec4 project(vec3 p, out float z) {
    vec3 d = p - o;
    float x = dot(d, R), y = dot(d, U);
    z = dot(d, F);
    float l = win.x, r = win.y, b = win.z, t = win.w, n = nf.x, f = nf.y;
    return vec4((2.0 * x - (r + l) * z) / (r - l), (2.0 * y - (t + b) * z) / (t - b),
                ((f + n) * z - 2.0 * f * n) / (f - n), z);
}
"""
VERT_DEPTH = (
    "#version 330\n"
    + _PROJECT
    + """
in vec3 p;
out float zv;
void main() { gl_Position = project(p, zv); }
"""
)
FRAG_DEPTH = """
#version 330
in float zv;
out float depth;
void main() { depth = zv; }
"""
VERT_EYE = (
    "#version 330\n"
    + _PROJECT
    + """
in vec3 p; in vec3 nrm;
out vec3 wp; flat out vec3 fn;
#ifdef SHADE
in vec3 alb; flat out vec3 fa;
#endif
void main() {
    float z;
    gl_Position = project(p, z);
    wp = p; fn = nrm;
#ifdef SHADE
    fa = alb;
#endif
}
"""
)
#: the eye pass's point: the fragment's world position and face normal, from the eye triangle
#: (forward: the shading runs per fragment that passes the depth test) ...
_EYE_FORWARD = """
#version 330
in vec3 wp; flat in vec3 fn;
#ifdef SHADE_FLOAT
float vis;                                           // (the colour's alpha)
#else
layout(location = 0) out float vis;
#endif
void shadow();
#ifdef SHADE
flat in vec3 fa;
vec3 albedo() { return fa; }
void shade();
void main() { shadow(); shade(); }
#else
void main() { shadow(); }
#endif
"""
#: ... or from the G-buffer (deferred: a full-screen pass shades each pixel once; a pixel without
#: a surface has w = 0 and gets the marker -1)
_EYE_DEFERRED = """
#version 330
uniform sampler2D gpos; uniform sampler2D gnrm;
vec3 wp; vec3 fn;
#ifdef SHADE_FLOAT
float vis;                                           // (the colour's alpha)
#else
layout(location = 0) out float vis;
#endif
void shadow();
#ifdef SHADE
uniform sampler2D galb;
vec3 albedo() { return texelFetch(galb, ivec2(gl_FragCoord.xy), 0).rgb; }
void shade();
void no_surface();
#endif
void main() {
    ivec2 c = ivec2(gl_FragCoord.xy);
    vec4 g = texelFetch(gpos, c, 0);
    if (g.w == 0.0) {
        vis = -1.0;
#ifdef SHADE
        no_surface();
#endif
        return;
    }
    wp = g.xyz;
    fn = texelFetch(gnrm, c, 0).xyz;
    shadow();
#ifdef SHADE
    shade();
#endif
}
"""
#: the G-buffer of the deferred eye pass (with VERT_EYE): world position, face normal (and with
#: SHADE the albedo)
FRAG_GBUFFER = """
#version 330
in vec3 wp; flat in vec3 fn;
layout(location = 0) out vec4 gpos;
layout(location = 1) out vec4 gnrm;
#ifdef SHADE
flat in vec3 fa;
layout(location = 2) out vec4 galb;
#endif
void main() {
    gpos = vec4(wp, 1.0); gnrm = vec4(fn, 0.0);
#ifdef SHADE
    galb = vec4(fa, 0.0);
#endif
}
"""
#: the shaded frame's colour (``shade``), after the shadow test: ``shading.shade``'s image, albedo x
#: (unshadowed direct light from the light centre x V + ambient), the same expression; "float": an
#: RGBA32F target with V in alpha, "rgba8": an RGBA8 target (clamped to [0, 1]) beside V's R32F
_FRAG_SHADE = """
#ifdef SHADE
uniform vec3 lc; uniform vec3 ln; uniform float rect; uniform float scale; uniform float ambient;
#ifdef SHADE_FLOAT
layout(location = 0) out vec4 color;                  // RGB, and V in alpha
#define ALPHA vis
#else
layout(location = 1) out vec4 color;
#define ALPHA 1.0
#endif
void shade() {
    vec3 n = eye_normal();
    vec3 d = lc - wp;
    float r2 = dot(d, d), r = sqrt(r2);
    float cp = max(dot(n, d) / r, 0.0);
    if (rect > 0.5) cp *= max(-dot(ln, d) / r, 0.0);
    color = vec4(albedo() * (scale * cp / r2 * vis + ambient), ALPHA);
}
void no_surface() { color = vec4(0.0, 0.0, 0.0, vis); }  // black, as ours (V: -1, the marker)
#endif
"""
#: what every eye pass's shadow test has: the light's map and view, the bias, helpers (after a head)
_FRAG_EYE_COMMON = """
uniform vec3 eye;
uniform vec3 lo; uniform vec3 lR; uniform vec3 lU; uniform vec3 lF;
uniform vec4 lwin; uniform vec2 lsize;
uniform float bias; uniform float slope_bias;
uniform sampler2D smap;

vec3 eye_normal() {                                  // the face normal turned toward the eye
    vec3 n = fn;
    if (dot(n, eye - wp) < 0.0) n = -n;
    return n;
}
vec3 light_project(vec3 p) {                         // (sx, sy) map texel coordinates, light depth
    vec3 d = p - lo;
    float x = dot(d, lR), y = dot(d, lU), z = dot(d, lF);
    float sx = (x / z - lwin.x) / (lwin.y - lwin.x) * lsize.x;
    float sy = (lwin.w - y / z) / (lwin.w - lwin.z) * lsize.y;   // row 0 at the top, as ours
    return vec3(sx, sy, z);
}
float receiver_offset(vec3 n, float z) {             // shadowmap.receiver_offset (world units)
    vec3 L = lo - wp;
    float c = clamp(abs(dot(n, L)) / max(length(L), 1e-30), 1e-3, 1.0);
    float tn = min(sqrt(1.0 - c * c) / c, 10.0);
    float texel = (lwin.y - lwin.x) / lsize.x * z;
    return texel * (bias + slope_bias * tn);
}
bool inside(int ci, int ri) { return !(ri < 0 || ri >= int(lsize.y) || ci < 0 || ci >= int(lsize.x)); }
float texel_depth(int ci, int ri) {                  // column ci, row ri from the top (as ours)
    return texelFetch(smap, ivec2(ci, int(lsize.y) - 1 - ri), 0).r;               // GL rows from the bottom
}
"""
FRAG_HARD = (
    _FRAG_EYE_COMMON
    + """
void shadow() {
    vec3 n = eye_normal();
    vec3 s = light_project(wp);
    float z = s.z;
    if (!(z > 0.0)) { vis = 1.0; return; }
    float zt = z - receiver_offset(n, z);
    int ci = int(floor(s.x)), ri = int(floor(s.y));
    if (!inside(ci, ri)) { vis = 1.0; return; }
    vis = (texel_depth(ci, ri) < zt) ? 0.0 : 1.0;
}
"""
)
#: ``pcss`` at its defaults (methods/pcss.py: blocker_search_kernel, penumbra_estimation,
#: filtering_kernel with receiver_plane and bilinear on, rotate off); NS, NF: the tap counts
FRAG_PCSS = (
    _FRAG_EYE_COMMON
    + """
uniform sampler2D zmin;                              // 1x1: the map's smallest depth
uniform float lnear;                                 // the light view's near plane (empty map)
uniform vec2 half_light;                             // half the light's size along the map's axes
uniform vec2 light_w;                                // the light's size along the map's axes
uniform vec2 search_pat[NS];
uniform vec2 filter_pat[NF];

float plane_depth(vec3 nv, float npo, float tx, float ty, float z) {   // pcss._plane_depth
    float xp = lwin.x + tx / lsize.x * (lwin.y - lwin.x);
    float yp = lwin.w - ty / lsize.y * (lwin.w - lwin.z);
    float den = nv.x * xp + nv.y * yp + nv.z;
    if (abs(den) < 1e-6) return z;
    float d = npo / den;
    if (!(d > 0.5 * z && d < 2.0 * z)) return z;
    return d;
}
float penumbra(float zr, float zb, float w) {        // pcss.penumbra_estimation
    if (!(zb > 0.0) || zr <= zb) return 0.0;
    return (zr - zb) * w / zb;
}
float lit(int ci, int ri, float zc) {                // texels outside the map are lit
    return (inside(ci, ri) && texel_depth(ci, ri) < zc) ? 0.0 : 1.0;
}
void shadow() {
    vec3 n = eye_normal();
    vec3 s = light_project(wp);
    float z = s.z;
    float zn = texelFetch(zmin, ivec2(0, 0), 0).r;
    if (!(zn < 1e38)) zn = lnear;                    // no occluder in the map
    zn = max(zn, 1e-9);
    if (!(z > zn)) { vis = 1.0; return; }
    float texel1 = (lwin.y - lwin.x) / lsize.x;      // texel size at depth 1
    // step 1: blocker search over the light's cross-section at depth zn, in texels
    vec2 rs = half_light * ((z - zn) / (z * zn) / texel1);
    if (s.x + rs.x < 0.0 || s.x - rs.x >= lsize.x || s.y + rs.y < 0.0 || s.y - rs.y >= lsize.y) {
        vis = 1.0;                                   // every search tap off the map: no blocker
        return;
    }
    float off = receiver_offset(n, z);
    float zt = z - off;
    vec3 nv = vec3(dot(n, lR), dot(n, lU), dot(n, lF));   // receiver plane in the light's view
    float npo = dot(n, wp - lo);
    float total = 0.0;
    int cnt = 0;
    for (int i = 0; i < NS; ++i) {
        float tx = s.x + search_pat[i].x * rs.x, ty = s.y - search_pat[i].y * rs.y;
        int ci = int(floor(tx)), ri = int(floor(ty));
        if (!inside(ci, ri)) continue;
        float d = texel_depth(ci, ri);
        if (d < plane_depth(nv, npo, tx, ty, z) - off) { total += d; cnt += 1; }
    }
    if (cnt == 0) { vis = 1.0; return; }             // no blocker: lit, no filtering
    float avg = total / float(cnt);
    // step 2: penumbra width (world) -> filter radius (texels at the receiver)
    vec2 w = vec2(penumbra(zt, avg, light_w.x), penumbra(zt, avg, light_w.y));
    vec2 rf = 0.5 * w / (texel1 * zt);
    // step 3: PCF, a bilinearly weighted 2x2 comparison per tap
    float acc = 0.0;
    for (int i = 0; i < NF; ++i) {
        float tx = s.x + filter_pat[i].x * rf.x, ty = s.y - filter_pat[i].y * rf.y;
        float zc = plane_depth(nv, npo, tx, ty, z) - off;
        float x = tx - 0.5, y = ty - 0.5;
        int x0 = int(floor(x)), y0 = int(floor(y));
        float fx = x - float(x0), fy = y - float(y0);
        acc += lit(x0, y0, zc) * ((1.0 - fx) * (1.0 - fy)) + lit(x0 + 1, y0, zc) * (fx * (1.0 - fy))
             + lit(x0, y0 + 1, zc) * ((1.0 - fx) * fy) + lit(x0 + 1, y0 + 1, zc) * (fx * fy);
    }
    vis = clamp(acc / float(NF), 0.0, 1.0);
}
"""
)
#: a triangle covering the viewport, from gl_VertexID (no vertex buffer)
VERT_FULL = """
#version 330
void main() { gl_Position = vec4(vec2((gl_VertexID << 1) & 2, gl_VertexID & 2) * 2.0 - 1.0, 0.0, 1.0); }
"""
#: the min of the ``block`` x ``block`` texels of ``src`` under this fragment (min reduction)
FRAG_MIN = """
#version 330
uniform sampler2D src;
uniform int block;
out float m;
void main() {
    ivec2 size = textureSize(src, 0);
    ivec2 c0 = ivec2(gl_FragCoord.xy) * block;
    ivec2 c1 = min(c0 + block, size);
    float v = 3.4e38;
    for (int y = c0.y; y < c1.y; ++y)
        for (int x = c0.x; x < c1.x; ++x) v = min(v, texelFetch(src, ivec2(x, y), 0).r);
    m = v;
}
"""
#: what the depth map is cleared to: no occluder (ours: +inf)
EMPTY_DEPTH = 3.0e38
#: the GL frame's shaded outputs (``GLFrame(shade=...)``): none (V only), our float32 colour, 8-bit
SHADES = (None, "float", "rgba8")


def _uniforms(prog, view, prefix=""):
    prog[prefix + "o"].value = tuple(map(float, view.origin))
    prog[prefix + "R"].value = tuple(map(float, view.right))
    prog[prefix + "U"].value = tuple(map(float, view.up))
    prog[prefix + "F"].value = tuple(map(float, view.forward))
    prog[prefix + "win"].value = tuple(map(float, view.window))


class GLUnavailable(RuntimeError):
    """No headless OpenGL 3.3 context on this machine (the peer is then skipped, with the reason)."""


def _context(moderngl):
    """A headless EGL context of GL 3.3 or later, else :class:`GLUnavailable`."""
    try:
        ctx = moderngl.create_standalone_context(backend="egl")
    except Exception as exc:  # no EGL, no driver
        raise GLUnavailable(str(exc).splitlines()[0] if str(exc) else type(exc).__name__) from exc
    if ctx.version_code < 330:
        ctx.release()
        raise GLUnavailable(f"OpenGL {ctx.version_code} < 3.3")
    return ctx


class GLFrame:
    """A shadow-map frame of ``scene`` in OpenGL (see the module docstring): the depth map, the eye
    pass with the shadow test ``frag_eye`` (a subclass's GLSL ``void shadow()`` that sets ``vis``
    from ``wp``, ``fn`` and the helpers of ``_FRAG_EYE_COMMON``), V read back. :meth:`frame`
    renders it and returns V (H,W) float32, NaN where no surface. Raises where no GL context can be
    made. Subclasses set ``frag_eye``, may add passes between the map and the eye pass
    (:meth:`_before_eye`), and set ``deferred`` where their test is costly: the eye triangles then
    write a G-buffer (world position, face normal; the same nearest fragment, the first drawn on a
    depth tie) and a full-screen pass runs the test once per pixel, not once per fragment that
    passes the depth test (overdraw)."""

    frag_eye = ""
    deferred = False
    #: GLSL ``#define`` lines for ``frag_eye``
    defines = ""

    def __init__(
        self, scene, width: int, height: int, map_size: int, bias: float, slope_bias: float, shade: str | None = None
    ):
        import moderngl

        if shade not in SHADES:
            raise ValueError(f"shade must be one of {', '.join(map(repr, SHADES))}, got {shade!r}")
        self.ctx = _context(moderngl)
        self.renderer = self.ctx.info.get("GL_RENDERER", "?")
        flat = scene.flat
        ctx = self.ctx
        self.shade = shade
        #: the shaded frame's image after each :meth:`frame`: (H,W,3) float32 ("float") or uint8
        #: ("rgba8", clamped linear); None without ``shade``
        self.image = None
        defines = (
            self.defines
            + {None: "", "float": "#define SHADE\n#define SHADE_FLOAT\n", "rgba8": "#define SHADE\n"}[shade]
        )

        def head(src):
            return src.replace("#version 330\n", "#version 330\n" + defines, 1)

        self.view = eye_view(scene, width, height)
        self.lview = fit_light_view(scene, map_size)
        tri = flat.vertices[flat.faces]  # (F,3,3) non-indexed: a flat face normal per vertex
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        occ = tri[flat.occluder]
        frag = head(_EYE_DEFERRED if self.deferred else _EYE_FORWARD) + self.frag_eye + _FRAG_SHADE
        self.p_depth = ctx.program(vertex_shader=VERT_DEPTH, fragment_shader=FRAG_DEPTH)
        vbo_occ = ctx.buffer(occ.astype("f4").tobytes())
        self.vao_depth = ctx.vertex_array(self.p_depth, [(vbo_occ, "3f", "p")])
        cols = [tri, np.repeat(fn[:, None, :], 3, axis=1)]
        attrs = ("3f 3f", "p", "nrm")
        if self.shade:  # the face's albedo at its corners (its mesh's, as shading.shade)
            alb = np.asarray(flat.albedo, np.float64)[flat.mesh_id]
            cols.append(np.repeat(alb[:, None, :], 3, axis=1))
            attrs = ("3f 3f 3f", "p", "nrm", "alb")
        self.vbo_eye = ctx.buffer(np.concatenate(cols, axis=2).astype("f4").tobytes())
        if self.deferred:
            self.p_eye = ctx.program(vertex_shader=VERT_FULL, fragment_shader=frag)
            self.vao_eye = ctx.vertex_array(self.p_eye, [])
            p_tri = self.p_gbuf = ctx.program(vertex_shader=head(VERT_EYE), fragment_shader=head(FRAG_GBUFFER))
            self.vao_gbuf = ctx.vertex_array(self.p_gbuf, [(self.vbo_eye, *attrs)])
            self.tex_g = [ctx.texture((width, height), 4, dtype="f4") for _ in range(3 if self.shade else 2)]
            for t in self.tex_g:
                t.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self.fbo_gbuf = ctx.framebuffer(self.tex_g, ctx.depth_renderbuffer((width, height)))
            for k, name in enumerate(("gpos", "gnrm", "galb")[: len(self.tex_g)]):
                self.p_eye[name].value = 2 + k
        else:
            p_tri = self.p_eye = ctx.program(vertex_shader=head(VERT_EYE), fragment_shader=frag)
            self.vao_eye = ctx.vertex_array(self.p_eye, [(self.vbo_eye, *attrs)])
        self.tex_map = ctx.texture((map_size, map_size), 1, dtype="f4")
        self.tex_map.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.fbo_map = ctx.framebuffer([self.tex_map], ctx.depth_renderbuffer((map_size, map_size)))
        # V (R32F); shaded "float": the colour with V in alpha (RGBA32F: one target, one clear, one
        # read; V in a target of its own was slower), "rgba8": V and the colour (RGBA8)
        packed = shade == "float"
        self.rb_v = ctx.renderbuffer((width, height), 4 if packed else 1, dtype="f4")
        targets = [self.rb_v]
        if shade == "rgba8":
            targets.append(ctx.renderbuffer((width, height), 4, dtype="f1"))
        if self.shade:
            from .shading import AMBIENT, exposure

            light = scene.light
            self.p_eye["lc"].value = tuple(map(float, light.center))
            rect = light.shape == "rect"
            self.p_eye["ln"].value = tuple(map(float, light.normal)) if rect else (0.0, 0.0, 0.0)
            self.p_eye["rect"].value = 1.0 if rect else 0.0
            self.p_eye["scale"].value = float(light.intensity * exposure(scene))
            self.p_eye["ambient"].value = float(AMBIENT)
        self.fbo_eye = ctx.framebuffer(targets, ctx.depth_renderbuffer((width, height)))
        lv, ev = self.lview, self.view
        _uniforms(self.p_depth, lv)
        self.p_depth["nf"].value = (float(lv.near), float(lv.far))
        _uniforms(p_tri, ev)
        p_tri["nf"].value = (float(ev.near), float(ev.far))
        for k, v in (("lo", lv.origin), ("lR", lv.right), ("lU", lv.up), ("lF", lv.forward)):
            self.p_eye[k].value = tuple(map(float, v))
        self.p_eye["lwin"].value = tuple(map(float, lv.window))
        self.p_eye["lsize"].value = (float(map_size), float(map_size))
        self.p_eye["eye"].value = tuple(map(float, scene.camera.eye))
        self.p_eye["bias"].value = float(bias)
        self.p_eye["slope_bias"].value = float(slope_bias)
        self.p_eye["smap"].value = 0
        self.width, self.height, self.map_size = width, height, map_size
        self.moderngl = moderngl

    def release(self) -> None:
        """Free the GL context and its objects."""
        self.ctx.release()

    def _before_eye(self) -> None:
        """Passes between the depth map and the eye pass (none for ``hard``)."""

    def frame(self) -> np.ndarray:
        with self.ctx:  # current on this thread (several peers may live in one process)
            return self._frame()

    def _frame(self) -> np.ndarray:
        ctx, mgl = self.ctx, self.moderngl
        ctx.enable(mgl.DEPTH_TEST)
        self.fbo_map.use()
        self.fbo_map.clear(EMPTY_DEPTH, 0.0, 0.0, 0.0, depth=1.0)
        self.vao_depth.render(mgl.TRIANGLES)
        self._before_eye()
        if self.deferred:
            self.fbo_gbuf.use()
            self.fbo_gbuf.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            self.vao_gbuf.render(mgl.TRIANGLES)
            ctx.disable(mgl.DEPTH_TEST)
            self.fbo_eye.use()
            self.tex_map.use(0)
            for k, t in enumerate(self.tex_g):  # position, normal (and albedo)
                t.use(2 + k)
            self.vao_eye.render(mgl.TRIANGLES, vertices=3)  # every pixel
        else:
            self.fbo_eye.use()
            # no surface: V -1 (the marker), black (an RGBA8 target clamps the -1 to 0)
            self.fbo_eye.clear(*((0.0, 0.0, 0.0, -1.0) if self.shade == "float" else (-1.0, 0.0, 0.0, 0.0)), depth=1.0)
            self.tex_map.use(0)
            self.vao_eye.render(mgl.TRIANGLES)
        k = 4 if self.shade == "float" else 1
        raw = self.fbo_eye.read(components=k, dtype="f4")
        px = np.frombuffer(raw, np.float32).reshape(self.height, self.width, k)[::-1]  # GL rows from the bottom
        v = px[:, :, k - 1]
        if self.shade == "float":
            self.image = px[:, :, :3]
        elif self.shade == "rgba8":
            raw = self.fbo_eye.read(components=4, attachment=1, dtype="f1")
            self.image = np.frombuffer(raw, np.uint8).reshape(self.height, self.width, 4)[::-1, :, :3]
        return np.where(v < 0.0, np.float32(np.nan), v)


class GLHard(GLFrame):
    """Our ``hard`` at its defaults: the Williams test, one texel per eye point."""

    frag_eye = FRAG_HARD


class GLPCSS(GLFrame):
    """Our ``pcss`` at its defaults (``rotate`` off, ``bilinear`` and ``receiver_plane`` on), with
    our tap patterns: ``search_samples`` and ``filter_samples`` taps of ``pattern``
    (``pcss.sample_pattern`` over the light's shape). Before the eye pass, the map's smallest depth
    (the search region's z_near, as ``pcss.occupancy_grid``) by a two-pass min reduction."""

    frag_eye = FRAG_PCSS
    deferred = True
    #: texels per side of a first-pass block of the min reduction
    MIN_BLOCK = 32

    def __init__(
        self,
        scene,
        width: int,
        height: int,
        map_size: int,
        bias: float,
        slope_bias: float,
        search_samples: int = 16,
        filter_samples: int = 16,
        pattern: str = "poisson",
        shade: str | None = None,
    ):
        from .methods.pcss import light_extent, sample_pattern

        disk = scene.light.shape != "rect"
        self.search_pat = sample_pattern(search_samples, pattern, disk)
        self.filter_pat = sample_pattern(filter_samples, pattern, disk)
        self.defines = f"#define NS {len(self.search_pat)}\n#define NF {len(self.filter_pat)}\n"
        super().__init__(scene, width, height, map_size, bias, slope_bias, shade)
        ctx, mgl, p = self.ctx, self.moderngl, self.p_eye
        ext = light_extent(scene.light)
        p["light_w"].value = tuple(map(float, ext))
        p["half_light"].value = tuple(map(float, 0.5 * ext))
        p["lnear"].value = float(self.lview.near)
        p["search_pat"].write(self.search_pat.astype("f4").tobytes())
        p["filter_pat"].write(self.filter_pat.astype("f4").tobytes())
        p["zmin"].value = 1
        # the min reduction: map -> g x g block minima -> 1 x 1
        g = -(-map_size // self.MIN_BLOCK)
        self.p_min = ctx.program(vertex_shader=VERT_FULL, fragment_shader=FRAG_MIN)
        self.p_min["src"].value = 0
        self.vao_min = ctx.vertex_array(self.p_min, [])
        self.tex_blocks = ctx.texture((g, g), 1, dtype="f4")
        self.tex_zmin = ctx.texture((1, 1), 1, dtype="f4")
        for t in (self.tex_blocks, self.tex_zmin):
            t.filter = (mgl.NEAREST, mgl.NEAREST)
        self.fbo_blocks = ctx.framebuffer([self.tex_blocks])
        self.fbo_zmin = ctx.framebuffer([self.tex_zmin])
        self.min_blocks = (self.MIN_BLOCK, g)

    def _before_eye(self) -> None:
        ctx, mgl = self.ctx, self.moderngl
        ctx.disable(mgl.DEPTH_TEST)
        for fbo, src, block in (
            (self.fbo_blocks, self.tex_map, self.min_blocks[0]),
            (self.fbo_zmin, self.tex_blocks, self.min_blocks[1]),
        ):
            fbo.use()
            src.use(0)
            self.p_min["block"].value = block
            self.vao_min.render(mgl.TRIANGLES, vertices=3)
        ctx.enable(mgl.DEPTH_TEST)
        self.tex_zmin.use(1)


#: the methods the peer renders, by our method name
PEERS = {"hard": GLHard, "pcss": GLPCSS}


def unavailable() -> str | None:
    """None where moderngl can be imported, else a one-line reason (the peer is optional)."""
    try:
        import moderngl  # noqa: F401
    except ImportError:
        return "moderngl is not installed (pip install -e '.[peer]')"
    return None


def make_peer(
    scene, width: int, height: int, map_size: int, bias: float, slope_bias: float, method: str = "hard", **params
):
    """(the GL frame of ``method``, None) or (None, a one-line reason) where moderngl or a GL 3.3
    context is missing. ``params``: the method's other parameters (``GLPCSS``'s tap counts and
    pattern) and ``shade`` (``GLFrame``'s)."""
    why = unavailable()
    if why is not None:
        return None, why
    try:
        return PEERS[method](scene, width, height, map_size, bias, slope_bias, **params), None
    except GLUnavailable as exc:  # no EGL / no GL 3.3 context on this machine (a shader error raises)
        return None, f"cannot create an OpenGL context: {exc}"


def method_defaults(name: str) -> dict:
    """A method's default parameters (the peer renders ``hard`` and ``pcss`` at their defaults)."""
    from .methods import get_method

    return {q.name: q.default for q in get_method(name).params}


def hard_defaults() -> dict:
    """``hard``'s default parameters."""
    return method_defaults("hard")


def peer_params(name: str, params: dict | None = None) -> dict:
    """``make_peer``'s keyword parameters for method ``name`` with ``params`` (None: its defaults),
    the ones other than ``map_size``, ``bias`` and ``slope_bias``; raises ValueError where a
    parameter has a value the GL frame does not implement (hard: ``pcf``; pcss: ``rotate``,
    ``bilinear``, ``receiver_plane``)."""
    p = method_defaults(name) if params is None else params
    if name == "hard":
        if p["pcf"]:
            raise ValueError("GLHard renders hard without PCF (pcf 0)")
        return {}
    if p["rotate"] or not p["bilinear"] or not p["receiver_plane"]:
        raise ValueError("GLPCSS renders pcss with rotate off, bilinear and receiver_plane on")
    return {k: p[k] for k in ("search_samples", "filter_samples", "pattern")}


#: |dV| within which a pixel of the GL frame counts as agreeing with ours: ``hard`` exactly; ``pcss``
#: within 0.02, between the float32 rounding of the GL's weights and radii (a few 1e-5) and a
#: discrete flip of one of its 16 filter taps (about 1/16); see ``benchmarks/gl_peer.py``
AGREEMENT_TOL = {"hard": 0.0, "pcss": 0.02}


def agreement(v_ours: np.ndarray, v_gl: np.ndarray, tol: float = 0.0) -> tuple[float, float, int]:
    """(fraction of the pixels both cover where V differs by more than ``tol``, fraction where the
    coverage differs, the number of pixels both cover)."""
    both = ~np.isnan(v_ours) & ~np.isnan(v_gl)
    n = int(both.sum())
    disagree = float(np.mean(np.abs(v_ours[both] - v_gl[both]) > tol)) if n else float("nan")
    cover = float(np.mean(np.isnan(v_ours) != np.isnan(v_gl)))
    return disagree, cover, n


#: colour difference within which a pixel of a shaded GL frame counts as shaded as ours: float32,
#: relative (float32 GLSL against our float64 arithmetic on float32 inputs: ~1e-6); 8-bit, the
#: colour clamped to [0, 1], absolute: one step of 1/255 (the rounding to 8 bits is half of one)
SHADE_RTOL = 1e-4
SHADE_ATOL_8BIT = 1.0 / 255.0


def shading_agreement(scene, v_gl: np.ndarray, img_gl: np.ndarray) -> tuple[float, int]:
    """(fraction of the pixels a shaded GL frame covers where its colour differs from our
    ``shading.shade`` of its own V by more than ``SHADE_RTOL``, relative, for a float32 image, or
    ``SHADE_ATOL_8BIT`` for an 8-bit one against ours clamped to [0, 1]; the number of those
    pixels). Our side shades with our eye G-buffer: a pixel where the two rasterizers keep a
    different nearest triangle (a crease or silhouette tie) gets another normal and differs."""
    from .raster import rasterize
    from .shading import shade

    h, w = v_gl.shape
    flat = scene.flat
    g = rasterize(eye_view(scene, w, h), flat.vertices, flat.faces, cull="none")
    cov = g.mask & ~np.isnan(v_gl)
    ours = shade(scene, g, np.where(cov, v_gl, np.float32(np.nan)))
    if img_gl.dtype == np.uint8:
        d = np.abs(np.clip(ours, 0.0, 1.0) - img_gl / np.float32(255.0)).max(axis=2)
        off = d > SHADE_ATOL_8BIT
    else:
        d = np.abs(ours - img_gl).max(axis=2) / np.maximum(np.abs(ours).max(axis=2), 1e-3)
        off = d > SHADE_RTOL
    n = int(cov.sum())
    return (float(np.mean(off[cov])) if n else float("nan")), n


def dv_stats(v_ours: np.ndarray, v_gl: np.ndarray) -> tuple[float, float]:
    """(mean |dV|, max |dV|) over the pixels both cover."""
    both = ~np.isnan(v_ours) & ~np.isnan(v_gl)
    if not both.any():
        return float("nan"), float("nan")
    d = np.abs(v_ours[both].astype(np.float64) - v_gl[both])
    return float(d.mean()), float(d.max())
