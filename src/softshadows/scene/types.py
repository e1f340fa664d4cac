"""Scene model: meshes with roles, area lights, a perspective camera.

All geometry is float64 in world space; right-handed, y up by default.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import SceneError
from ..geometry.vectors import cross3

ROLES = ("both", "occluder", "receiver")


#: the one rule for a camera's vertical field of view (degrees), shared by Camera and the loader
FOV_Y_RANGE = (0.0, 179.0)


def fov_y_problem(fov) -> str | None:
    """None when ``fov`` is a valid ``fov_y``, else what is expected (one rule, open interval)."""
    lo, hi = FOV_Y_RANGE
    if not _is_number(fov) or not (lo < float(fov) < hi):
        return f"a number of degrees in ({lo:g}, {hi:g})"
    return None


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _number(x, what: str, *, gt=None, ge=None) -> float:
    """A finite real number (not a bool or a string), else SceneError naming ``what``."""
    if not _is_number(x) or not np.isfinite(x):
        raise SceneError(f"{what} must be a finite number, got {x!r}")
    if gt is not None and not x > gt:
        raise SceneError(f"{what} must be > {gt}, got {x!r}")
    if ge is not None and not x >= ge:
        raise SceneError(f"{what} must be >= {ge}, got {x!r}")
    return float(x)


def _vec3(x, what: str) -> np.ndarray:
    if isinstance(x, (str, bytes, bool, np.bool_)):
        raise SceneError(f"{what}: expected 3 numbers, got {x!r}")
    try:
        a = np.asarray(x, dtype=np.float64).reshape(3)
    except Exception:
        raise SceneError(f"{what}: expected 3 numbers, got {x!r}") from None
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{what}: non-finite value {a.tolist()}")
    return a


class Mesh:
    """A triangle mesh. ``role`` is ``both`` (casts and receives), ``occluder`` or ``receiver``.

    Degenerate triangles (zero area, repeated indices) are dropped with a warning; NaN/inf
    vertices or out-of-range indices raise :class:`SceneError`.
    """

    def __init__(self, vertices, faces, albedo=(0.8, 0.8, 0.8), role: str = "both", name: str = "mesh"):
        if not isinstance(name, str):
            raise SceneError(f"mesh name must be a string, got {name!r}")
        try:
            v = np.asarray(vertices, dtype=np.float64)
        except (TypeError, ValueError):
            raise SceneError(f"mesh '{name}': vertices must be numbers of shape (N,3)") from None
        try:
            f = np.asarray(faces)
        except (TypeError, ValueError):
            raise SceneError(f"mesh '{name}': faces must be integers of shape (M,3)") from None
        if f.dtype.kind not in "iuf" and f.size:
            raise SceneError(f"mesh '{name}': faces must be integers of shape (M,3), got dtype {f.dtype}")
        if v.ndim != 2 or v.shape[1] != 3:
            raise SceneError(f"mesh '{name}': vertices must have shape (N,3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise SceneError(f"mesh '{name}': faces must have shape (M,3), got {f.shape}")
        if not np.all(np.isfinite(v)):
            bad = int(np.argwhere(~np.isfinite(v).all(axis=1))[0, 0])
            raise SceneError(f"mesh '{name}': vertex {bad} is not finite ({v[bad].tolist()})")
        if f.size and (not np.issubdtype(f.dtype, np.integer)) and not np.all(np.equal(np.mod(f, 1), 0)):
            raise SceneError(f"mesh '{name}': face indices must be integers")
        f = f.astype(np.int64)
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise SceneError(f"mesh '{name}': face index out of range [0, {len(v)})")
        if not isinstance(role, str) or role not in ROLES:
            raise SceneError(f"mesh '{name}': role must be one of {', '.join(ROLES)}, got '{role}'")
        try:
            if isinstance(albedo, (str, bytes)):
                raise TypeError
            alb = np.asarray(albedo, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise SceneError(f"mesh '{name}': albedo must be 3 non-negative numbers, got {albedo!r}") from None
        if alb.size == 1:
            alb = np.repeat(alb, 3)
        if alb.size != 3 or not np.all(np.isfinite(alb)) or alb.min() < 0:
            raise SceneError(f"mesh '{name}': albedo must be 3 non-negative numbers, got {albedo!r}")
        if len(f):
            a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
            area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
            scale = max(float(np.ptp(v, axis=0).max()), 1e-30)
            good = (area2 > 1e-12 * scale * scale) & (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
            nbad = int((~good).sum())
            if nbad:
                warnings.warn(f"mesh '{name}': dropped {nbad} degenerate triangle(s)", stacklevel=2)
                f = f[good]
        if len(f) == 0:
            raise SceneError(f"mesh '{name}': no non-degenerate triangles")
        self.vertices = np.ascontiguousarray(v)
        self.faces = np.ascontiguousarray(f)
        self.albedo = tuple(float(x) for x in alb)
        self.role = role
        self.name = name

    def transformed(self, matrix: np.ndarray) -> Mesh:
        m = np.asarray(matrix, dtype=np.float64)
        vh = np.c_[self.vertices, np.ones(len(self.vertices))] @ m.T
        faces = self.faces if np.linalg.det(m[:3, :3]) > 0 else self.faces[:, ::-1]
        return Mesh(vh[:, :3], faces, self.albedo, self.role, self.name)

    def __repr__(self) -> str:
        return f"Mesh('{self.name}', {len(self.vertices)} vertices, {len(self.faces)} faces, role={self.role})"


class RectLight:
    """The rectangle ``center +- u/2 +- v/2`` (u, v full edge vectors), emitting toward normalize(u x v)."""

    shape = "rect"

    def __init__(self, center, u, v, intensity: float = 1.0):
        self.center = _vec3(center, "light.center")
        self.u = _vec3(u, "light.u")
        self.v = _vec3(v, "light.v")
        n = np.cross(self.u, self.v)
        lu, lv = np.linalg.norm(self.u), np.linalg.norm(self.v)
        # relative test (u, v parallel or zero), so that lights of any scale are accepted
        if not (lu > 0 and lv > 0) or np.linalg.norm(n) <= 1e-9 * lu * lv:
            raise SceneError(f"light: rectangle has zero area (u={self.u.tolist()}, v={self.v.tolist()})")
        self.intensity = _number(intensity, "light.intensity", ge=0)

    @property
    def normal(self) -> np.ndarray:
        n = cross3(self.u, self.v)
        return n / np.linalg.norm(n)

    @property
    def area(self) -> float:
        return float(np.linalg.norm(cross3(self.u, self.v)))

    @property
    def size(self) -> float:
        """Characteristic size: the longer edge length."""
        return float(max(np.linalg.norm(self.u), np.linalg.norm(self.v)))

    @property
    def equivalent_radius(self) -> float:
        """Radius of the disk with the same area (used by sphere-light methods)."""
        return float(np.sqrt(self.area / np.pi))

    def scaled(self, factor: float) -> RectLight:
        return RectLight(self.center, self.u * factor, self.v * factor, self.intensity)

    def __repr__(self) -> str:
        return f"RectLight(center={self.center.tolist()}, u={self.u.tolist()}, v={self.v.tolist()}, intensity={self.intensity})"


class SphereLight:
    """A sphere light. V is the visible fraction of the disk of this radius through the center, facing p."""

    shape = "sphere"

    def __init__(self, center, radius: float, intensity: float = 1.0):
        self.center = _vec3(center, "light.center")
        self.radius = _number(radius, "light.radius", gt=0)
        self.intensity = _number(intensity, "light.intensity", ge=0)

    @property
    def area(self) -> float:
        return float(np.pi * self.radius**2)

    @property
    def size(self) -> float:
        return 2.0 * self.radius

    @property
    def equivalent_radius(self) -> float:
        return self.radius

    def scaled(self, factor: float) -> SphereLight:
        return SphereLight(self.center, self.radius * factor, self.intensity)

    def __repr__(self) -> str:
        return f"SphereLight(center={self.center.tolist()}, radius={self.radius}, intensity={self.intensity})"


def rect_to_sphere(light: RectLight) -> SphereLight:
    """Sphere light of equal emitting (disk) area at the same center."""
    return SphereLight(light.center, light.equivalent_radius, light.intensity)


def sphere_to_rect(light: SphereLight, direction=None) -> RectLight:
    """Square light of equal area at the same center, facing ``direction`` (default: down, -y)."""
    d = np.array([0.0, -1.0, 0.0]) if direction is None else np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(a, d)
    u /= np.linalg.norm(u)
    v = np.cross(d, u)  # u x v = d
    side = np.sqrt(light.area)
    return RectLight(light.center, u * side, v * side, light.intensity)


class Camera:
    """Perspective camera; ``fov_y`` in degrees."""

    def __init__(self, eye, target, up=(0.0, 1.0, 0.0), fov_y: float = 45.0):
        self.eye = _vec3(eye, "camera.eye")
        self.target = _vec3(target, "camera.target")
        self.up = _vec3(up, "camera.up")
        if np.linalg.norm(self.target - self.eye) < 1e-12:
            raise SceneError("camera: eye and target coincide")
        fwd = (self.target - self.eye) / np.linalg.norm(self.target - self.eye)
        if np.linalg.norm(np.cross(fwd, self.up)) < 1e-9:
            raise SceneError(f"camera: up {self.up.tolist()} is zero or parallel to the view direction")
        if (why := fov_y_problem(fov_y)) is not None:
            raise SceneError(f"camera.fov_y must be {why}, got {fov_y!r}")
        self.fov_y = float(fov_y)

    def __repr__(self) -> str:
        return f"Camera(eye={self.eye.tolist()}, target={self.target.tolist()}, fov_y={self.fov_y})"


def light_key(light) -> tuple:
    """The values that define a light (a cache key: equal lights give equal keys)."""
    vals = [light.center, getattr(light, "u", ()), getattr(light, "v", ()), [getattr(light, "radius", 0.0)]]
    return (light.shape, light.intensity, *(float(x) for a in vals for x in np.ravel(a)))


@dataclass
class FlatGeometry:
    """All meshes of a scene concatenated: what kernels consume (plain arrays)."""

    vertices: np.ndarray  # (V,3) float64
    faces: np.ndarray  # (F,3) int64
    mesh_id: np.ndarray  # (F,) int32, index into Scene.meshes
    occluder: np.ndarray  # (F,) bool: casts shadows (role both|occluder)
    receiver: np.ndarray  # (F,) bool: receives shadows (role both|receiver)
    albedo: np.ndarray  # (n_meshes,3) float64
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def face_vertices(self, which: str = "occluder") -> np.ndarray:
        """Sorted indices of the vertices used by the ``occluder``, ``receiver`` or ``all`` faces
        (computed once: the arrays of a scene's flat geometry are not modified in place)."""
        hit = self._cache.get(("face_vertices", which))
        if hit is None:
            mask = {"occluder": self.occluder, "receiver": self.receiver}.get(which)
            hit = np.unique(self.faces if mask is None else self.faces[mask])
            self._cache[("face_vertices", which)] = hit
        return hit

    def faces_where(self, mask: np.ndarray) -> np.ndarray:
        """Contiguous ``faces[mask]``; computed once per geometry when ``mask`` is one of the role masks
        (``occluder``, ``receiver``: the shadow maps' faces, every frame) — a copy of every selected
        face otherwise."""
        which = "occluder" if mask is self.occluder else "receiver" if mask is self.receiver else None
        if which is None:
            return np.ascontiguousarray(self.faces[mask])
        hit = self._cache.get(("faces_where", which))
        if hit is None:
            hit = self._cache[("faces_where", which)] = np.ascontiguousarray(self.faces[mask])
            hit.flags.writeable = False
        return hit

    def cached(self, key: tuple, compute):
        """``compute()``, once per geometry and ``key`` (per-frame scene preparation that depends
        only on the geometry and on what ``key`` names, e.g. :func:`light_key` and map sizes)."""
        hit = self._cache.get(key)
        if hit is None:
            hit = self._cache[key] = compute()
        return hit

    def subset(self, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertices, faces, original face index) for the faces in ``mask``."""
        idx = np.nonzero(mask)[0]
        return self.vertices, np.ascontiguousarray(self.faces[idx]), idx


@dataclass
class Scene:
    meshes: list
    light: object
    camera: Camera
    name: str = "scene"
    _flat: FlatGeometry | None = field(default=None, repr=False, compare=False)
    _norm: tuple | None = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise SceneError(f"scene name must be a string, got {self.name!r}")
        if isinstance(self.meshes, Mesh):
            self.meshes = [self.meshes]
        if not isinstance(self.meshes, (list, tuple)):
            raise SceneError(f"scene '{self.name}': meshes must be a list of Mesh, got {type(self.meshes).__name__}")
        self.meshes = list(self.meshes)
        if not self.meshes:
            raise SceneError(f"scene '{self.name}': no meshes")
        for i, m in enumerate(self.meshes):
            if not isinstance(m, Mesh):
                raise SceneError(f"scene '{self.name}': meshes[{i}] must be a Mesh, got {type(m).__name__}")
        if not isinstance(self.light, (RectLight, SphereLight)):
            raise SceneError(
                f"scene '{self.name}': light must be a RectLight or SphereLight, got {type(self.light).__name__}"
            )
        if not isinstance(self.camera, Camera):
            raise SceneError(f"scene '{self.name}': camera must be a Camera, got {type(self.camera).__name__}")

    @property
    def flat(self) -> FlatGeometry:
        if self._flat is None:
            vs, fs, ids, occ, rec = [], [], [], [], []
            off = 0
            for i, m in enumerate(self.meshes):
                vs.append(m.vertices)
                fs.append(m.faces + off)
                off += len(m.vertices)
                n = len(m.faces)
                ids.append(np.full(n, i, np.int32))
                occ.append(np.full(n, m.role in ("both", "occluder")))
                rec.append(np.full(n, m.role in ("both", "receiver")))
            self._flat = FlatGeometry(
                np.ascontiguousarray(np.concatenate(vs)),
                np.ascontiguousarray(np.concatenate(fs)),
                np.concatenate(ids),
                np.concatenate(occ),
                np.concatenate(rec),
                np.array([m.albedo for m in self.meshes], dtype=np.float64),
            )
        return self._flat

    @property
    def has_roles(self) -> bool:
        """True when at least one mesh is a pure occluder or a pure receiver."""
        return any(m.role != "both" for m in self.meshes)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        flat = self.flat
        hit = flat._cache.get("bounds")  # once per geometry (a pass over every vertex)
        if hit is None:
            v = flat.vertices
            hit = flat._cache["bounds"] = (v.min(axis=0), v.max(axis=0))
        return hit[0].copy(), hit[1].copy()

    def normalized(self) -> tuple[Scene, np.ndarray, float]:
        """``(scene', shift, scale)`` with ``scene' = (scene - shift) * scale`` (a similarity, so V is
        the same): what every kernel and Embree receive (:func:`softshadows.render`).

        Kernels and Embree work partly in float32. A scene far from the origin (georeferenced,
        e.g. 1e6..1e8 units away with metre-sized objects) loses its detail in float32, and one of
        tiny or huge extent meets absolute epsilons (near planes, degeneracy tests). So, in float64:
        when the meshes' bounding-box centre is more than ``RECENTRE_AT`` x their extent E from the
        origin, shift = that centre (else 0); when E is outside ``RESCALE_OUTSIDE``,
        scale = 2**-round(log2 E) (exact in binary; else 1). Scenes near the origin with an extent
        of 1e-2..1e4 units (all built-in scenes) are returned as they are (same object)."""
        # a light or camera assigned after the first call is seen (compared by identity)
        if self._norm is None or self._norm[3][0] is not self.light or self._norm[3][1] is not self.camera:
            key = (self.light, self.camera)
            v = self.flat.vertices
            lo, hi = v.min(axis=0), v.max(axis=0)
            ext = float(np.max(hi - lo))
            c = (lo + hi) / 2
            shift = c if float(np.max(np.abs(c))) > RECENTRE_AT * max(ext, 1e-300) else np.zeros(3)
            scale = 1.0
            if ext > 0 and not (RESCALE_OUTSIDE[0] <= ext <= RESCALE_OUTSIDE[1]):
                scale = float(2.0 ** -round(np.log2(ext)))
            if not shift.any() and scale == 1.0:
                self._norm = (self, np.zeros(3), 1.0, key)
            else:
                self._norm = (_similar_scene(self, shift, scale), shift, scale, key)
        return self._norm[:3]

    def with_light(self, light) -> Scene:
        # same meshes: the flattened geometry and what is cached on it are shared
        return Scene(self.meshes, light, self.camera, self.name, _flat=self._flat)

    def with_camera(self, camera) -> Scene:
        return Scene(self.meshes, self.light, camera, self.name, _flat=self._flat)


#: recentre a scene whose bounding-box centre is further than this x its extent from the origin
RECENTRE_AT = 16.0
#: rescale a scene whose extent (largest bounding-box side) is outside this range
RESCALE_OUTSIDE = (1e-2, 1e4)


def _similar_scene(scene: Scene, shift: np.ndarray, scale: float) -> Scene:
    """``(scene - shift) * scale`` in float64 (already validated input: no re-validation)."""

    def pt(p):
        return (np.asarray(p, np.float64) - shift) * scale

    meshes = []
    for m in scene.meshes:
        mm = object.__new__(Mesh)
        mm.vertices = np.ascontiguousarray(pt(m.vertices))
        mm.faces, mm.albedo, mm.role, mm.name = m.faces, m.albedo, m.role, m.name
        meshes.append(mm)
    light = scene.light
    if light.shape == "rect":
        lt = object.__new__(RectLight)
        lt.center, lt.u, lt.v = pt(light.center), light.u * scale, light.v * scale
    else:
        lt = object.__new__(SphereLight)
        lt.center, lt.radius = pt(light.center), light.radius * scale
    lt.intensity = light.intensity
    cam = object.__new__(Camera)
    cam.eye, cam.target, cam.up, cam.fov_y = (
        pt(scene.camera.eye),
        pt(scene.camera.target),
        scene.camera.up,
        scene.camera.fov_y,
    )
    out = Scene(meshes, lt, cam, scene.name)
    out._norm = (out, np.zeros(3), 1.0, (lt, cam))
    return out


def warn(msg: str) -> None:
    warnings.warn(msg, stacklevel=3)
