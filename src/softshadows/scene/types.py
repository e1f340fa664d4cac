"""Scene model: meshes with roles, area lights, a perspective camera.

All geometry is float64 in world space; right-handed, y up by default.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import SceneError

ROLES = ("both", "occluder", "receiver")


def _vec3(x, what: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64).reshape(3)
    except Exception as exc:
        raise SceneError(f"{what}: expected 3 numbers, got {x!r}") from exc
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{what}: non-finite value {a.tolist()}")
    return a


class Mesh:
    """A triangle mesh. ``role`` is ``both`` (casts and receives), ``occluder`` or ``receiver``.

    Degenerate triangles (zero area, repeated indices) are dropped with a warning; NaN/inf
    vertices or out-of-range indices raise :class:`SceneError`.
    """

    def __init__(self, vertices, faces, albedo=(0.8, 0.8, 0.8), role: str = "both", name: str = "mesh"):
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
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
        if role not in ROLES:
            raise SceneError(f"mesh '{name}': role must be one of {', '.join(ROLES)}, got '{role}'")
        alb = np.asarray(albedo, dtype=np.float64).reshape(-1)
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
        if np.linalg.norm(n) < 1e-12 or np.linalg.norm(self.u) < 1e-9 or np.linalg.norm(self.v) < 1e-9:
            raise SceneError(f"light: rectangle has zero area (u={self.u.tolist()}, v={self.v.tolist()})")
        if not np.isfinite(intensity) or intensity < 0:
            raise SceneError(f"light.intensity must be finite and >= 0, got {intensity}")
        self.intensity = float(intensity)

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.u, self.v)
        return n / np.linalg.norm(n)

    @property
    def area(self) -> float:
        return float(np.linalg.norm(np.cross(self.u, self.v)))

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
        if not np.isfinite(radius) or radius <= 0:
            raise SceneError(f"light.radius must be > 0, got {radius}")
        if not np.isfinite(intensity) or intensity < 0:
            raise SceneError(f"light.intensity must be finite and >= 0, got {intensity}")
        self.radius = float(radius)
        self.intensity = float(intensity)

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
            raise SceneError("camera: up is parallel to the view direction")
        if not (0.0 < fov_y < 179.0):
            raise SceneError(f"camera.fov_y must be in (0, 179) degrees, got {fov_y}")
        self.fov_y = float(fov_y)

    def __repr__(self) -> str:
        return f"Camera(eye={self.eye.tolist()}, target={self.target.tolist()}, fov_y={self.fov_y})"


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

    def __post_init__(self):
        if not self.meshes:
            raise SceneError(f"scene '{self.name}': no meshes")
        if not isinstance(self.light, (RectLight, SphereLight)):
            raise SceneError(f"scene '{self.name}': light must be a RectLight or SphereLight")

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
        v = self.flat.vertices
        return v.min(axis=0), v.max(axis=0)

    def with_light(self, light) -> Scene:
        return Scene(self.meshes, light, self.camera, self.name)

    def with_camera(self, camera) -> Scene:
        return Scene(self.meshes, self.light, camera, self.name)


def warn(msg: str) -> None:
    warnings.warn(msg, stacklevel=3)
