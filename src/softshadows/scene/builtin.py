"""Built-in scenes: ``BUILTIN[name] = (description, builder)``; ``builder(light="rect"|"sphere")``.

Every scene has a ground plane at y = 0 (an ``8 x 8`` plane of ``8 x 8`` cells, role
``receiver``, albedo 0.8 grey), one or more objects with role ``occluder`` (pass
``object_role="both"`` to let them shadow themselves), a light facing down (rect: ``u x v`` is
along -y; ``light="sphere"`` gives :func:`rect_to_sphere` of it: same center, equal area) and a
camera about 35-40 degrees above the horizon that frames the objects and their whole penumbra at
both 4:3 and 1:1. The coordinates are documented in each builder (tests depend on them).

:func:`shadow_footprint` and :func:`frame_camera` are the helpers that placed these cameras; the
loaders use them to frame scenes that come without a camera.
"""

from __future__ import annotations

import functools
from importlib import resources

import numpy as np

from ..errors import SceneError
from . import primitives as prim
from .types import Camera, Mesh, RectLight, Scene, rect_to_sphere, sphere_to_rect

__all__ = [
    "BUILTIN",
    "GROUND_ALBEDO",
    "GROUND_SIZE",
    "SQUARE_LIGHT_SIDE",
    "SQUARE_LIGHT_Y",
    "SQUARE_OCCLUDER_SIDE",
    "SQUARE_OCCLUDER_Y",
    "build",
    "builtin_scenes",
    "frame_camera",
    "shadow_footprint",
    "square_visibility",
    "with_light_shape",
]

GROUND_SIZE = 8.0
GROUND_CELLS = 8
GROUND_ALBEDO = (0.8, 0.8, 0.8)

# The analytic case: a horizontal square occluder below a parallel square light, both centered on the y axis.
SQUARE_OCCLUDER_Y = 1.0
SQUARE_OCCLUDER_SIDE = 1.0
SQUARE_LIGHT_Y = 3.0
SQUARE_LIGHT_SIDE = 1.0


# ---- helpers ---------------------------------------------------------------------------------
def with_light_shape(scene: Scene, shape: str | None) -> Scene:
    """The scene with its light as ``shape`` ("rect" | "sphere"; None keeps it). Conversions keep
    the center and the emitting area (:func:`rect_to_sphere`; :func:`sphere_to_rect` faces -y)."""
    if shape is None or shape == scene.light.shape:
        return scene
    if shape == "sphere":
        return scene.with_light(rect_to_sphere(scene.light))
    if shape == "rect":
        return scene.with_light(sphere_to_rect(scene.light))
    raise SceneError(f"light shape must be 'rect' or 'sphere', got {shape!r}")


def _light_samples(light) -> np.ndarray:
    """Points whose central projections bound the light's shadows: rect corners, or the corners of
    the disk's bounding square facing -y (a conservative bound for a sphere above the scene)."""
    if light.shape == "rect":
        u, v = light.u / 2, light.v / 2
    else:
        u = np.array([light.radius, 0.0, 0.0])
        v = np.array([0.0, 0.0, light.radius])
    c = light.center
    return np.array([c - u - v, c + u - v, c + u + v, c - u + v])


def shadow_footprint(light, points, ground_y: float = 0.0) -> np.ndarray:
    """Projections onto the plane y = ``ground_y`` of ``points`` (occluder vertices) from the
    light's corners: their convex hull contains the umbra and the whole penumbra. Points at or
    above the light's height cast nothing downward and are skipped."""
    p = np.asarray(points, float).reshape(-1, 3)
    out = []
    for c in _light_samples(light):
        h = c[1] - p[:, 1]
        ok = h > 1e-6 * max(1.0, abs(c[1] - ground_y))
        t = (c[1] - ground_y) / h[ok]
        out.append(c + (p[ok] - c) * t[:, None])
    return np.concatenate(out) if out else np.zeros((0, 3))


def frame_camera(
    points,
    target=None,
    azimuth_deg: float = 20.0,
    elevation_deg: float = 38.0,
    fov_y: float = 40.0,
    margin: float = 0.1,
) -> Camera:
    """A camera looking at ``target`` (default: the points' bounding-box center) from
    ``elevation_deg`` above the horizon and ``azimuth_deg`` around y (0 = from +z), as close as
    possible while every point lies inside the central ``1 - margin`` of a square (1:1) image,
    hence also of any wider one (4:3)."""
    p = np.asarray(points, float).reshape(-1, 3)
    tgt = (p.min(axis=0) + p.max(axis=0)) / 2 if target is None else np.asarray(target, float)
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    d = np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
    fwd = -d
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    lim = np.tan(np.radians(fov_y) / 2) * (1.0 - margin)

    def fits(dist: float) -> bool:
        q = p - (tgt + d * dist)
        z = q @ fwd
        if np.any(z <= 1e-9):
            return False
        return bool(np.all(np.abs(q @ right) <= lim * z) and np.all(np.abs(q @ up) <= lim * z))

    lo, hi = 1e-3, 1.0
    while not fits(hi):
        hi *= 2.0
        if hi > 1e9:
            raise SceneError("cannot frame the scene: points are not finite or too spread out")
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return Camera(tgt + d * hi, tgt, (0.0, 1.0, 0.0), fov_y)


def _ground(
    size: float = GROUND_SIZE, y: float = 0.0, center=(0.0, 0.0, 0.0), albedo=GROUND_ALBEDO, cells: int = GROUND_CELLS
) -> Mesh:
    v, f = prim.plane(size, size, cells, cells, y=y, center=center)
    return Mesh(v, f, albedo, "receiver", "ground")


def _down_light(center, side: float, intensity: float = 1.0) -> RectLight:
    """Square light of edge ``side`` at ``center`` facing -y: u = +x, v = +z, u x v = -y."""
    return RectLight(center, (side, 0.0, 0.0), (0.0, 0.0, side), intensity)


def _finish(name: str, meshes: list, light: RectLight, camera: Camera, shape: str) -> Scene:
    return with_light_shape(Scene(meshes, light, camera, name), shape)


# ---- the scenes ------------------------------------------------------------------------------
def square(light: str = "rect", object_role: str = "occluder") -> Scene:
    """The analytic case: parallel square occluder and square light.

    * ground: y = 0, 8 x 8 centered at the origin, receiver.
    * occluder: one quad (2 triangles), side ``SQUARE_OCCLUDER_SIDE`` = 1.0, horizontal at
      y = ``SQUARE_OCCLUDER_Y`` = 1.0, spanning x, z in [-0.5, 0.5], normal +y (facing the light).
    * light: center (0, ``SQUARE_LIGHT_Y`` = 3.0, 0), u = (1, 0, 0), v = (0, 0, 1)
      (side ``SQUARE_LIGHT_SIDE`` = 1.0, facing -y).
    * On the ground the umbra is |x|, |z| <= 0.5 and the penumbra reaches |x| or |z| = 1.0;
      :func:`square_visibility` gives V in closed form.
    * camera: eye (0, 2.92, 2.88), target (0, 0.5, 0), fov_y 40 (40 degrees above the horizon).
    """
    s = SQUARE_OCCLUDER_SIDE
    v, f = prim.quad((0.0, SQUARE_OCCLUDER_Y, 0.0), (0.0, 0.0, s), (s, 0.0, 0.0))  # (+z) x (+x) = +y
    occ = Mesh(v, f, (0.85, 0.3, 0.25), object_role, "square")
    lt = _down_light((0.0, SQUARE_LIGHT_Y, 0.0), SQUARE_LIGHT_SIDE)
    cam = Camera((0.0, 2.92, 2.88), (0.0, 0.5, 0.0), (0.0, 1.0, 0.0), 40.0)
    return _finish("square", [_ground(), occ], lt, cam, light)


def square_visibility(points) -> np.ndarray:
    """Closed-form V of the ``square`` scene's rect light at ``points`` (K,3) below the occluder
    (y < ``SQUARE_OCCLUDER_Y``): 1 - (area of the light covered by the occluder's projection
    through p onto the light's plane) / (light area). The overlap is separable in x and z."""
    from ..analytic import rect_occluder_visibility

    ho, hl = SQUARE_OCCLUDER_SIDE / 2, SQUARE_LIGHT_SIDE / 2
    return rect_occluder_visibility(
        points, (0.0, SQUARE_OCCLUDER_Y, 0.0), (ho, ho), (0.0, SQUARE_LIGHT_Y, 0.0), (hl, hl)
    )


def spheres(light: str = "rect", object_role: str = "occluder") -> Scene:
    """Three intersecting icospheres (3 subdivisions, 1,280 triangles each) whose shadows overlap.

    * red:   center (-0.50, 1.00, -0.20), radius 0.50
    * green: center ( 0.35, 1.40, -0.10), radius 0.45
    * blue:  center (-0.05, 0.75,  0.45), radius 0.40
    (red intersects green and blue; all three shadows overlap.)
    * light: center (0.5, 3.2, 0.4), side 0.8 (u = 0.8 x, v = 0.8 z, facing -y).
    * camera: eye (1.25, 4.62, 4.10), target (-0.37, 0.92, -0.35), fov_y 40.
    """
    specs = [
        ((-0.5, 1.0, -0.2), 0.5, (0.85, 0.25, 0.2), "red sphere"),
        ((0.35, 1.4, -0.1), 0.45, (0.3, 0.7, 0.3), "green sphere"),
        ((-0.05, 0.75, 0.45), 0.4, (0.25, 0.4, 0.85), "blue sphere"),
    ]
    meshes = [_ground()]
    for c, r, alb, nm in specs:
        v, f = prim.icosphere(r, c, 3)
        meshes.append(Mesh(v, f, alb, object_role, nm))
    lt = _down_light((0.5, 3.2, 0.4), 0.8)
    cam = Camera((1.25, 4.62, 4.10), (-0.37, 0.92, -0.35), (0.0, 1.0, 0.0), 40.0)
    return _finish("spheres", meshes, lt, cam, light)


FENCE_BAR_WIDTH = 0.05
FENCE_GAP = 0.17
FENCE_LOW_Y = 0.6
FENCE_HIGH_Y = 1.0


def fence(light: str = "rect", object_role: str = "occluder") -> Scene:
    """A floating lattice of thin bars parallel to the ground: light leaks and high frequencies.

    * bars: boxes 0.05 wide, 0.04 thick (y), 2.0 long; pitch 0.22 (gap 0.17).
    * lower layer: 9 bars along z at x = -0.88 + 0.22 i (i = 0..8), centered at y = 0.6;
      its penumbra (about 0.15) is narrower than the pitch, so stripes stay visible.
    * upper layer: 9 bars along x at z = -0.88 + 0.22 j, centered at y = 1.0 (penumbra about
      0.3, wider than the pitch: a blurred, leaky grid).
    * light: center (0, 3, 0), side 0.6 (facing -y).
    * camera: eye (1.86, 5.07, 5.10), target (0, 0.51, 0), fov_y 40.
    """
    pitch = FENCE_BAR_WIDTH + FENCE_GAP
    offs = (np.arange(9) - 4) * pitch
    parts_lo = [prim.box((FENCE_BAR_WIDTH, 0.04, 2.0), (x, FENCE_LOW_Y, 0.0)) for x in offs]
    parts_hi = [prim.box((2.0, 0.04, FENCE_BAR_WIDTH), (0.0, FENCE_HIGH_Y, z)) for z in offs]
    lo = Mesh(*prim.merge(*parts_lo), (0.75, 0.55, 0.3), object_role, "lower bars")
    hi = Mesh(*prim.merge(*parts_hi), (0.35, 0.5, 0.75), object_role, "upper bars")
    lt = _down_light((0.0, 3.0, 0.0), 0.6)
    cam = Camera((1.86, 5.07, 5.10), (0.0, 0.51, 0.0), (0.0, 1.0, 0.0), 40.0)
    return _finish("fence", [_ground(), lo, hi], lt, cam, light)


CONTACT_BOX_SIZE = (1.0, 0.8, 0.6)


def contact(light: str = "rect", object_role: str = "occluder") -> Scene:
    """A box resting on the ground, lit from the side: contact hardening.

    * box: 1.0 (x) x 0.8 (y) x 0.6 (z), x in [-0.5, 0.5], y in [0, 0.8] (bottom face exactly on
      the ground), z in [-0.3, 0.3]; 12 triangles.
    * light: center (-1.8, 3.0, 0.0), side 0.8 (facing -y): the shadow stretches toward +x
      to about x = 1.5, sharp where it meets the box and soft at its far end.
    * camera: eye (1.68, 2.36, 2.54), target (0.49, 0.40, 0), fov_y 40.
    """
    v, f = prim.box(CONTACT_BOX_SIZE, (0.0, CONTACT_BOX_SIZE[1] / 2, 0.0))
    v[np.isclose(v[:, 1], 0.0), 1] = 0.0  # exactly on the ground
    bx = Mesh(v, f, (0.3, 0.45, 0.8), object_role, "box")
    lt = _down_light((-1.8, 3.0, 0.0), 0.8)
    cam = Camera((1.68, 2.36, 2.54), (0.49, 0.40, 0.0), (0.0, 1.0, 0.0), 40.0)
    return _finish("contact", [_ground(), bx], lt, cam, light)


PLANT_SEED = 20240601
PLANT_LEAVES = 2600
PLANT_LEAF_SEGMENTS = 8


def _plant_geometry(seed: int = PLANT_SEED):
    """(pot, stem and branches, leaves) as (vertices, faces) pairs; deterministic for a seed."""
    rng = np.random.default_rng(seed)
    pot = prim.cylinder(0.18, (0.0, 0.0, 0.0), (0.0, 0.2, 0.0), 24, True)
    parts = [prim.cylinder(0.025, (0.0, 0.0, 0.0), (0.0, 1.5, 0.0), 12, True)]
    # branches: from the stem at heights 0.35..1.4, golden-angle azimuths, rising 25..55 degrees
    nb = 14
    hb = np.linspace(0.35, 1.4, nb)
    az = np.arange(nb) * np.radians(137.5) + rng.uniform(-0.2, 0.2, nb)
    el = np.radians(rng.uniform(25, 55, nb))
    lb = 0.6 - 0.3 * (hb - 0.35) / 1.05 + rng.uniform(-0.05, 0.05, nb)
    dirs = np.stack([np.cos(el) * np.cos(az), np.sin(el), np.cos(el) * np.sin(az)], 1)
    starts = np.stack([np.zeros(nb), hb, np.zeros(nb)], 1)
    ends = starts + dirs * lb[:, None]
    for s, e in zip(starts, ends):
        parts.append(prim.cylinder(0.012, s, e, 8, True))
    # leaf anchor lines: the branches and the top of the stem
    a0 = np.vstack([starts, [[0.0, 1.1, 0.0]]])
    a1 = np.vstack([ends, [[0.0, 1.5, 0.0]]])
    w = np.linalg.norm(a1 - a0, axis=1)
    which = rng.choice(len(a0), PLANT_LEAVES, p=w / w.sum())
    t = rng.uniform(0.15, 1.0, PLANT_LEAVES)
    anchor = a0[which] + (a1[which] - a0[which]) * t[:, None] + rng.normal(0, 0.04, (PLANT_LEAVES, 3))
    axis = a1[which] - a0[which]
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    out = rng.normal(size=(PLANT_LEAVES, 3))
    out -= (out * axis).sum(1, keepdims=True) * axis  # leaves point away from their branch
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    major = out + 0.3 * axis + np.array([0.0, 0.25, 0.0])
    normal = rng.normal(size=(PLANT_LEAVES, 3)) * 0.6 + np.array([0.0, 1.0, 0.0])  # mostly facing up
    length = rng.uniform(0.04, 0.08, PLANT_LEAVES)
    centers = anchor + out * (length[:, None] / 2 + 0.01)
    leaves = prim.ellipse_fans(centers, major, normal, length, 0.45 * length, PLANT_LEAF_SEGMENTS, cup=0.15)
    return pot, prim.merge(*parts), leaves


def plant(light: str = "rect", object_role: str = "occluder") -> Scene:
    """A procedural potted plant about 1.5 tall (fixed seed ``PLANT_SEED``): many layers of small
    leaves that shadow each other and the ground.

    * pot: capped cylinder, radius 0.18, y in [0, 0.2], centered on the y axis (96 triangles).
    * stem: radius 0.025 from (0, 0, 0) to (0, 1.5, 0); 14 branches (radius 0.012, length
      0.3-0.6) leave it at heights 0.35-1.4, rising 25-55 degrees.
    * leaves: 2,600 cupped ellipses 0.04-0.08 long (8 triangles each, 20,800 in all) along the
      branches and the top of the stem; the canopy spans roughly x in [-0.45, 0.45],
      z in [-0.65, 0.5], y in [0.3, 1.7].
    * total: 21,392 object triangles (plus the 128 of the ground).
    * light: center (0.3, 3.5, 0.2), side 0.7 (facing -y).
    * camera: eye (1.02, 3.43, 3.34), target (-0.24, 0.85, -0.12), fov_y 40.
    """
    pot, stem, leaves = _plant_geometry()
    meshes = [
        _ground(),
        Mesh(*pot, (0.7, 0.35, 0.2), object_role, "pot"),
        Mesh(*stem, (0.4, 0.3, 0.15), object_role, "stem"),
        Mesh(*leaves, (0.25, 0.6, 0.2), object_role, "leaves"),
    ]
    lt = _down_light((0.3, 3.5, 0.2), 0.7)
    cam = Camera((1.02, 3.43, 3.34), (-0.24, 0.85, -0.12), (0.0, 1.0, 0.0), 40.0)
    return _finish("plant", meshes, lt, cam, light)


@functools.lru_cache(maxsize=1)
def _bunny_arrays() -> tuple[np.ndarray, np.ndarray]:
    """The shipped decimated bunny (package data ``data/bunny.npz``), read once."""
    ref = resources.files("softshadows").joinpath("data", "bunny.npz")
    with ref.open("rb") as fh, np.load(fh) as z:
        return z["vertices"].astype(np.float64), z["faces"].astype(np.int64)


def bunny(light: str = "rect", object_role: str = "occluder") -> Scene:
    """The Stanford bunny (Turk & Levoy 1994), decimated to 10,000 triangles, shipped as package
    data (see ``data/ATTRIBUTION.md``).

    * bunny: 1.2 tall resting on y = 0, bounding box x in [-0.61, 0.61], z in [-0.47, 0.47]
      (centered on the y axis), head and ears toward -x, -z, as scanned (y up); 5,029 vertices.
    * light: center (0.5, 3.2, 0.4), side 0.8 (facing -y).
    * camera: eye (0.73, 2.92, 2.48), target (-0.28, 0.60, -0.30), fov_y 40.
    """
    v, f = _bunny_arrays()
    b = Mesh(v, f, (0.85, 0.75, 0.6), object_role, "bunny")
    lt = _down_light((0.5, 3.2, 0.4), 0.8)
    cam = Camera((0.73, 2.92, 2.48), (-0.28, 0.60, -0.30), (0.0, 1.0, 0.0), 40.0)
    return _finish("bunny", [_ground(), b], lt, cam, light)


def icosphere(level: int, light: str = "rect") -> Scene:
    """The triangle-throughput scene (``softshadows bench icosphere --sweep triangles``): an icosphere
    of radius 0.6 centred at y = 1 with 20 * 4^level triangles (trimesh's subdivision; level 8:
    1.3 M) over a ground quad of 2 triangles, a 0.8 x 0.8 rect light at (0.3, 3, 0.2) facing down
    (sphere light: the disk of the same area), camera framing the ball and the shadow."""
    import trimesh  # imported lazily: slow to import, only needed here

    level = int(level)
    if not 0 <= level <= 10:
        raise SceneError(f"icosphere level must be in 0..10, got {level}")
    sph = trimesh.creation.icosphere(subdivisions=level, radius=0.6)
    verts = np.asarray(sph.vertices, dtype=np.float64) + [0.0, 1.0, 0.0]
    ground = Mesh([[-4, 0, -4], [4, 0, -4], [4, 0, 4], [-4, 0, 4]], [[0, 2, 1], [0, 3, 2]], role="receiver")
    ball = Mesh(verts, np.asarray(sph.faces, dtype=np.int64), albedo=(0.8, 0.3, 0.2), role="occluder")
    rect = RectLight(center=(0.3, 3.0, 0.2), u=(0.8, 0, 0), v=(0, 0, 0.8))
    cam = frame_camera(np.vstack([verts, [[-2.5, 0, -2.5], [2.5, 0, 2.5]]]))
    return _finish(f"icosphere-{level}", [ground, ball], rect, cam, light)


BUILTIN: dict = {
    "square": ("analytic case: square occluder under a parallel square light (closed-form V)", square),
    "spheres": ("three intersecting spheres with overlapping shadows", spheres),
    "fence": ("floating lattice of thin bars: light leaks and high-frequency shadows", fence),
    "contact": ("box resting on the ground lit from the side: contact hardening", contact),
    "plant": ("procedural potted plant, 21k triangles of small leaves: many overlapping occluders", plant),
    "bunny": ("Stanford bunny (decimated to 10k triangles) on the ground", bunny),
}


def builtin_scenes() -> dict[str, str]:
    """Built-in scene names and one-line descriptions."""
    return {k: d for k, (d, _) in BUILTIN.items()}


def build(name: str, light: str | None = None, **kw) -> Scene:
    """Build the built-in scene ``name`` (light "rect", the default, or "sphere")."""
    if name not in BUILTIN:
        raise SceneError(f"unknown built-in scene '{name}'; built-in scenes: {', '.join(BUILTIN)}")
    if light not in (None, "rect", "sphere"):
        raise SceneError(f"light must be 'rect' or 'sphere', got {light!r}")
    return BUILTIN[name][1](light=light or "rect", **kw)
