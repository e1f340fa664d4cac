"""Loading scenes: built-in names, TOML scene files, and bare mesh files.

:func:`load_scene` accepts

* a built-in scene name (``square``, ``spheres``, ``fence``, ``contact``, ``plant``, ``bunny``;
  see :mod:`softshadows.scene.builtin`);
* a ``.toml`` scene file (format below);
* a mesh file (``.obj .ply .glb .gltf .stl .off``, read with trimesh; a multi-part file such as a
  glTF scene is flattened into one triangle mesh with its node transforms applied). The object
  keeps its units and position. It becomes an ``occluder`` resting on a ``receiver`` ground
  plane at its lowest y (centered under it, 4x its largest extent ``E`` wide); a square light of
  side ``0.5 E`` facing -y sits ``2 E`` above its top (offset by ``0.3 E`` in x and ``0.2 E`` in z
  so that the shadow shows); the camera (fov_y 40, 35 degrees above the horizon) frames the
  object and its whole shadow.

``light="rect"`` or ``"sphere"`` converts the scene's light to that shape at equal emitting area
and the same center (:func:`~softshadows.scene.rect_to_sphere`, and
:func:`~softshadows.scene.sphere_to_rect` facing -y); ``None`` keeps the scene's own.
Every problem raises :class:`~softshadows.errors.SceneError` with a one-line message that names
the file and the field.

TOML scene files
----------------

A full example (every key shown; the comments say which are optional)::

    name = "bunny on a table"        # optional; default: the file name without extension
    ground = { size = 10, albedo = [0.8, 0.8, 0.8] }
    # optional, and (TOML rules) before the first [table]: a receiver plane facing +y, centered
    # under the meshes at their lowest y; keys: size (default 4x the meshes' largest extent),
    # albedo (0.8 grey), cells (8), y (default: the meshes' lowest y); `ground = true`: defaults.

    [camera]                         # optional; default: framed automatically (like mesh files)
    eye = [0, 3, 6]
    target = [0, 0.5, 0]
    up = [0, 1, 0]                   # optional, default [0, 1, 0]
    fov_y = 45                       # optional, degrees, default 45

    [light]                          # optional; default: a square light above the meshes
    type = "rect"                    # "rect" (default) or "sphere"
    center = [0, 4, 0]
    u = [1, 0, 0]                    # rect: full edge vectors; it emits toward u x v
    v = [0, 0, 1]                    #   (here (0, -1, 0): down)
    intensity = 1.0                  # optional, default 1
    # radius = 0.5                   # sphere (with type = "sphere"): radius > 0

    [[mesh]]                         # one table per mesh, at least one
    path = "models/bunny.obj"        # a mesh file, relative to this TOML file's folder
    name = "bunny"                   # optional; default: the file name or the primitive
    albedo = [0.8, 0.7, 0.6]         # optional, 3 numbers in [0, 1] (or one grey), default 0.8
    role = "occluder"                # optional: "both" (default), "occluder" or "receiver"
    translate = [0, -0.25, 0]        # optional transform: scale, then rotate, then translate
    rotate = [0, 90, 0]              #   degrees about x, then y, then z (right-handed)
    scale = 8.0                      #   a number or [sx, sy, sz] (non-zero)
    # matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    #                                # a 4x4 affine matrix instead of translate/rotate/scale

    [[mesh]]
    primitive = "box"                # a procedural mesh instead of path; its own fields:
    size = [2, 0.1, 1]               #   plane:    size = s or [sx, sz] (10), cells = n or [nx, nz] (1),
    center = [0, -0.05, 0]           #             center; faces +y
    albedo = 0.5                     #   box:      size = s or [sx, sy, sz] (1), center
    role = "both"                    #   sphere:   radius (1), center, subdivisions (3, 0..6)
                                     #   quad:     center, u, v (full edges; faces u x v)
                                     #   cylinder: radius (0.5), height (1), center, segments (32); along y
                                     # center defaults to [0, 0, 0]; the transform keys apply too


Unknown keys are errors (a typo should not be silently ignored).
"""

from __future__ import annotations

import io
import math
import os
import tomllib
from pathlib import Path

import numpy as np

from ..errors import SceneError
from . import primitives as prim
from .builtin import BUILTIN, build, frame_camera, shadow_footprint, with_light_shape
from .types import ROLES, Camera, Mesh, RectLight, Scene, SphereLight, fov_y_problem

__all__ = ["MESH_EXTENSIONS", "load_scene", "load_toml", "read_mesh_file", "scene_from_mesh"]

MESH_EXTENSIONS = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")

_TOP_KEYS = ("name", "camera", "light", "mesh", "ground")
_CAMERA_KEYS = ("eye", "target", "up", "fov_y")
_RECT_KEYS = ("type", "center", "u", "v", "intensity")
_SPHERE_KEYS = ("type", "center", "radius", "intensity")
_MESH_KEYS = ("path", "primitive", "name", "albedo", "role", "translate", "rotate", "scale", "matrix")
_PRIMITIVE_KEYS = {
    "plane": ("size", "cells", "center"),
    "box": ("size", "center"),
    "sphere": ("radius", "center", "subdivisions"),
    "quad": ("center", "u", "v"),
    "cylinder": ("radius", "height", "center", "segments"),
}
_GROUND_KEYS = ("size", "albedo", "cells", "y")
_REQUIRED = object()


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _strip(exc, prefix: str) -> str:
    """A constructor's message without its own 'camera: ' / 'light: ' prefix."""
    msg = _one_line(exc)
    return msg[len(prefix) + 2 :] if msg.startswith(prefix + ": ") else msg


def _choices() -> str:
    return f"built-in scenes: {', '.join(BUILTIN)}; or a .toml scene file or a mesh file ({' '.join(MESH_EXTENSIONS)})"


# ---- entry point -----------------------------------------------------------------------------
def load_scene(name_or_path, light: str | None = None) -> Scene:
    """A :class:`Scene` from a built-in name, a ``.toml`` scene file or a mesh file (see the
    module docstring); ``light`` = "rect" | "sphere" converts the light (equal area), None keeps it."""
    if light not in (None, "rect", "sphere"):
        raise SceneError(f"light must be 'rect' or 'sphere', got {light!r}")
    if isinstance(name_or_path, str) and name_or_path in BUILTIN:
        return build(name_or_path, light)
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise SceneError(f"scene must be a name or a file path, got {type(name_or_path).__name__}; {_choices()}")
    if not str(name_or_path).strip():
        raise SceneError(f"scene is empty; {_choices()}")
    path = Path(name_or_path)
    suffix = path.suffix.lower()
    if suffix == ".toml":
        scene = load_toml(path)
    elif suffix in MESH_EXTENSIONS:
        v, f = read_mesh_file(path, str(path))
        scene = scene_from_mesh(v, f, name=path.stem)
    elif path.exists():
        raise SceneError(f"{path}: unsupported file type '{path.suffix}'; {_choices()}")
    else:
        raise SceneError(f"unknown scene '{name_or_path}'; {_choices()}")
    return with_light_shape(scene, light)


# ---- mesh files ------------------------------------------------------------------------------
def read_mesh_file(path, label: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N,3) float64, faces (M,3) int64) of a mesh file, all its parts concatenated with
    their transforms applied. ``label`` prefixes error messages (default: the path)."""
    import trimesh  # imported lazily: it is slow to import and only needed here

    path = Path(path)
    label = str(path) if label is None else label
    if not path.is_file():
        raise SceneError(f"{label}: file not found")
    try:
        if path.suffix.lower() == ".gltf":
            _check_gltf_buffers(path, label)
        if path.suffix.lower() == ".obj":  # text: decoded here (UTF-8, else Latin-1), MTL files too
            obj = trimesh.load(
                io.BytesIO(_utf8(path.read_bytes())),
                file_type="obj",
                resolver=_text_resolver(path.parent),
                process=False,
            )
        else:
            obj = trimesh.load(str(path), process=False)
    except SceneError:
        raise
    except Exception as exc:
        raise SceneError(f"{label}: cannot read mesh: {_one_line(exc) or type(exc).__name__}") from None
    parts = []
    if isinstance(obj, trimesh.Scene):
        for node in obj.graph.nodes_geometry:
            transform, gname = obj.graph[node]
            g = obj.geometry.get(gname)
            if isinstance(g, trimesh.Trimesh) and len(g.faces):
                v = np.asarray(g.vertices, np.float64)
                t = np.asarray(transform, np.float64)
                v = v @ t[:3, :3].T + t[:3, 3]
                f = np.asarray(g.faces, np.int64)
                parts.append((v, f if np.linalg.det(t[:3, :3]) >= 0 else f[:, ::-1]))
    elif isinstance(obj, trimesh.Trimesh) and len(obj.faces):
        parts.append((np.asarray(obj.vertices, np.float64), np.asarray(obj.faces, np.int64)))
    if not parts:
        raise SceneError(f"{label}: no triangles in the file")
    v, f = prim.merge(*parts)
    finite = np.isfinite(v).all(axis=1)
    if not finite.all():
        bad = int(np.argmin(finite))
        raise SceneError(f"{label}: vertex {bad} is not finite ({v[bad].tolist()})")
    return v, f


def _utf8(data: bytes) -> bytes:
    """Text bytes as UTF-8: kept when they are UTF-8 (a BOM dropped), else read as Latin-1 (every
    byte is a character: comments and names in legacy encodings load instead of failing)."""
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        data.decode("utf-8")
        return data
    except UnicodeDecodeError:
        return data.decode("latin-1").encode("utf-8")


def _text_resolver(folder: Path):
    """A trimesh resolver for an OBJ's side files that re-encodes text ones (.mtl) as UTF-8."""
    from trimesh.resolvers import FilePathResolver

    class _Resolver(FilePathResolver):
        def get(self, name):
            data = super().get(name)
            return _utf8(data) if str(name).lower().endswith(".mtl") and isinstance(data, bytes) else data

    return _Resolver(str(folder))


def _check_gltf_buffers(path: Path, label: str) -> None:
    """A .gltf's external buffers must exist: name the missing one (trimesh's message does not)."""
    import json
    from urllib.parse import unquote

    try:
        doc = json.loads(_utf8(path.read_bytes()).decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise SceneError(f"{label}: not a glTF JSON file: {_one_line(exc)}") from None
    buffers = doc.get("buffers", []) if isinstance(doc, dict) else []
    for i, b in enumerate(buffers if isinstance(buffers, list) else []):
        uri = b.get("uri") if isinstance(b, dict) else None
        if isinstance(uri, str) and not uri.startswith("data:") and not (path.parent / unquote(uri)).is_file():
            raise SceneError(f"{label}: buffer {i} file '{uri}' not found (next to the .gltf)")


def _auto_light(lo: np.ndarray, hi: np.ndarray) -> RectLight:
    """A square light facing -y: side 0.5 E, 2 E above the top, offset (0.3 E, 0.2 E) in x, z."""
    ext = float(np.max(hi - lo))
    c = (lo + hi) / 2
    side = 0.5 * ext
    return RectLight((c[0] + 0.3 * ext, hi[1] + 2.0 * ext, c[2] + 0.2 * ext), (side, 0, 0), (0, 0, side))


def _bbox_corners(lo, hi) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _auto_camera(lo, hi, light, ground_y: float) -> Camera:
    corners = _bbox_corners(lo, hi)
    pts = np.vstack([corners, shadow_footprint(light, corners, ground_y)])
    return frame_camera(pts, azimuth_deg=25.0, elevation_deg=35.0, fov_y=40.0, margin=0.12)


def _ground_mesh(lo, hi, size=None, y=None, albedo=(0.8, 0.8, 0.8), cells: int = 8) -> Mesh:
    ext = float(np.max(hi - lo))
    size = 4.0 * ext if size is None else size
    y = lo[1] if y is None else y
    c = (lo + hi) / 2
    v, f = prim.plane(size, size, cells, cells, y=0.0, center=(c[0], y, c[2]))
    return Mesh(v, f, albedo, "receiver", "ground")


def scene_from_mesh(vertices, faces, name: str = "mesh", albedo=(0.75, 0.65, 0.55)) -> Scene:
    """A mesh alone, staged: occluder on a receiver ground at its lowest y, light above, camera
    framing it (see the module docstring for the numbers)."""
    v = np.asarray(vertices, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    if float(np.max(hi - lo)) <= 0:
        raise SceneError(f"mesh '{name}': has no extent")
    try:
        obj = Mesh(v, faces, albedo, "occluder", name)
    except SceneError as exc:
        raise SceneError(f"{name}: {exc}") from None
    light = _auto_light(lo, hi)
    return Scene([_ground_mesh(lo, hi), obj], light, _auto_camera(lo, hi, light, lo[1]), name)


# ---- TOML field readers ----------------------------------------------------------------------
class _Fields:
    """Reads and validates the fields of one TOML table; errors name file, table and key."""

    def __init__(self, file: str, table: dict, where: str, allowed, sep: str = "."):
        self.file, self.t, self.where, self.sep = file, table, where, sep
        if not isinstance(table, dict):
            self.fail(f"{where} must be a table, got {_one_line(repr(table))[:80]}")
        unknown = [k for k in table if k not in allowed]
        if unknown:
            names = ", ".join(f"'{k}'" for k in unknown)
            self.fail(f"{where}: unknown key{'s' if len(unknown) > 1 else ''} {names}; valid: {', '.join(allowed)}")

    def field(self, key: str) -> str:
        return f"{self.where}{self.sep}{key}"

    def fail(self, msg: str):
        raise SceneError(f"{self.file}: {msg}")

    def has(self, key: str) -> bool:
        return key in self.t

    def _get(self, key, default):
        if key not in self.t:
            if default is _REQUIRED:
                self.fail(f"{self.field(key)} is required")
            return default, False
        return self.t[key], True

    @staticmethod
    def _is_num(x) -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool)

    def num(self, key, default=_REQUIRED, *, gt=None, ge=None, le=None, integer=False):
        x, given = self._get(key, default)
        if not given:
            return x
        if not self._is_num(x) or not math.isfinite(x) or (integer and int(x) != x):
            self.fail(f"{self.field(key)} must be {'an integer' if integer else 'a number'}, got {x!r}")
        if gt is not None and not x > gt:
            self.fail(f"{self.field(key)} must be > {gt}, got {x!r}")
        if ge is not None and not x >= ge:
            self.fail(f"{self.field(key)} must be >= {ge}, got {x!r}")
        if le is not None and not x <= le:
            self.fail(f"{self.field(key)} must be <= {le}, got {x!r}")
        return int(x) if integer else float(x)

    def vec(
        self,
        key,
        n: int = 3,
        default=_REQUIRED,
        *,
        scalar_ok=False,
        gt=None,
        ge=None,
        le=None,
        nonzero=False,
        integer=False,
    ):
        x, given = self._get(key, default)
        if not given:
            return None if x is None else np.asarray(x, np.float64)
        orig = x
        if scalar_ok and self._is_num(x):
            x = [x] * n
        ok = isinstance(x, list) and len(x) == n and all(self._is_num(e) and math.isfinite(e) for e in x)
        if ok and integer:
            ok = all(int(e) == e for e in x)
        what = f"{n} {'integers' if integer else 'numbers'}" + (" (or one)" if scalar_ok else "")
        if ok and gt is not None:
            ok, what = all(e > gt for e in x), what + f" > {gt}"
        if ok and ge is not None:
            ok, what = all(e >= ge for e in x), what + f" >= {ge}"
        if ok and le is not None:
            ok, what = all(e <= le for e in x), what + f" <= {le}"
        if ok and nonzero:
            ok, what = all(e != 0 for e in x), what + ", non-zero"
        if not ok:
            self.fail(f"{self.field(key)} must be {what}, got {orig!r}")
        return np.asarray(x, np.float64)

    def string(self, key, default=_REQUIRED, choices=None) -> str:
        x, given = self._get(key, default)
        if not given:
            return x
        if not isinstance(x, str):
            self.fail(f"{self.field(key)} must be a string, got {x!r}")
        if choices is not None and x not in choices:
            self.fail(f"{self.field(key)} must be one of {', '.join(choices)}, got {x!r}")
        return x

    def matrix4(self, key) -> np.ndarray:
        x = self.t[key]
        ok = (
            isinstance(x, list)
            and len(x) == 4
            and all(
                isinstance(r, list) and len(r) == 4 and all(self._is_num(e) and math.isfinite(e) for e in r) for r in x
            )
        )
        if not ok:
            self.fail(f"{self.field(key)} must be 4 rows of 4 numbers, got {_one_line(repr(x))}")
        m = np.asarray(x, np.float64)
        if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-9):
            self.fail(f"{self.field(key)} must be affine (last row [0, 0, 0, 1]), got {m[3].tolist()}")
        if abs(np.linalg.det(m[:3, :3])) < 1e-12:
            self.fail(f"{self.field(key)} is singular")
        return m


def _rotation_xyz(deg) -> np.ndarray:
    """R = Rz @ Ry @ Rx: rotate about x first, then y, then z (degrees, right-handed)."""
    ax, ay, az = np.radians(deg)
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _transform(fl: _Fields) -> np.ndarray | None:
    """The 4x4 matrix of a [[mesh]] entry, or None when it has no transform keys."""
    trs = [k for k in ("translate", "rotate", "scale") if fl.has(k)]
    if fl.has("matrix"):
        if trs:
            fl.fail(f"{fl.field('matrix')} cannot be combined with {', '.join(trs)}")
        return fl.matrix4("matrix")
    if not trs:
        return None
    s = fl.vec("scale", default=[1.0, 1.0, 1.0], scalar_ok=True, nonzero=True)
    r = fl.vec("rotate", default=[0.0, 0.0, 0.0])
    t = fl.vec("translate", default=[0.0, 0.0, 0.0])
    m = np.eye(4)
    m[:3, :3] = _rotation_xyz(r) @ np.diag(s)
    m[:3, 3] = t
    return m


def _primitive(fl: _Fields, kind: str) -> tuple[np.ndarray, np.ndarray]:
    center = fl.vec("center", default=[0.0, 0.0, 0.0])
    if kind == "plane":
        size = fl.vec("size", 2, default=[10.0, 10.0], scalar_ok=True, gt=0)
        cells = fl.vec("cells", 2, default=[1, 1], scalar_ok=True, integer=True, ge=1, le=1000)
        return prim.plane(size[0], size[1], int(cells[0]), int(cells[1]), center=center)
    if kind == "box":
        return prim.box(fl.vec("size", default=[1.0, 1.0, 1.0], scalar_ok=True, gt=0), center)
    if kind == "sphere":
        return prim.icosphere(fl.num("radius", 1.0, gt=0), center, fl.num("subdivisions", 3, integer=True, ge=0, le=6))
    if kind == "quad":
        u, v = fl.vec("u"), fl.vec("v")
        if np.linalg.norm(np.cross(u, v)) <= 1e-9 * np.linalg.norm(u) * np.linalg.norm(v):
            fl.fail(f"{fl.field('u')} x {fl.field('v')} must have non-zero area, got u={u.tolist()}, v={v.tolist()}")
        return prim.quad(center, u, v)
    # cylinder
    r = fl.num("radius", 0.5, gt=0)
    h = fl.num("height", 1.0, gt=0)
    n = fl.num("segments", 32, integer=True, ge=3, le=4096)
    return prim.cylinder(r, center - [0, h / 2, 0], center + [0, h / 2, 0], n, True)


def _mesh_entry(file: str, base: Path, entry, i: int) -> Mesh:
    where = f"[[mesh]] #{i}"
    if not isinstance(entry, dict):
        raise SceneError(f"{file}: {where} must be a table, got {entry!r}")
    kind = entry.get("primitive")
    extra = _PRIMITIVE_KEYS.get(kind, ()) if isinstance(kind, str) else ()
    fl = _Fields(file, entry, where, _MESH_KEYS + extra, sep=": ")
    if fl.has("path") == fl.has("primitive"):
        fl.fail(f"{where}: needs exactly one of 'path' or 'primitive'")
    if fl.has("primitive"):
        kind = fl.string("primitive", choices=tuple(_PRIMITIVE_KEYS))
        v, f = _primitive(fl, kind)
        default_name = f"{kind} #{i}"
    else:
        rel = fl.string("path")
        p = Path(rel).expanduser()
        p = p if p.is_absolute() else base / p
        if p.suffix.lower() not in MESH_EXTENSIONS:
            fl.fail(f"{where}: path '{rel}' is not a mesh file ({' '.join(MESH_EXTENSIONS)})")
        if not p.is_file():
            fl.fail(f"{where}: path '{rel}' not found")
        v, f = read_mesh_file(p, f"{file}: {where}: path '{rel}'")
        default_name = p.stem
    name = fl.string("name", default_name)
    albedo = fl.vec("albedo", default=[0.8, 0.8, 0.8], scalar_ok=True, ge=0, le=1)
    role = fl.string("role", "both", choices=ROLES)
    m = _transform(fl)
    if m is not None:
        v = v @ m[:3, :3].T + m[:3, 3]
        if np.linalg.det(m[:3, :3]) < 0:  # mirrored: keep the normals pointing outward
            f = f[:, ::-1]
    try:
        return Mesh(v, f, albedo, role, name)
    except SceneError as exc:
        raise SceneError(f"{file}: {where}: {exc}") from None


def _light(file: str, table) -> RectLight | SphereLight:
    if not isinstance(table, dict):
        raise SceneError(f"{file}: [light] must be a table, got {table!r}")
    kind = table.get("type", "sphere" if "radius" in table else "rect")
    if kind not in ("rect", "sphere"):
        raise SceneError(f"{file}: [light].type must be one of rect, sphere, got {kind!r}")
    fl = _Fields(file, table, "[light]", _RECT_KEYS if kind == "rect" else _SPHERE_KEYS)
    center = fl.vec("center")
    intensity = fl.num("intensity", 1.0, ge=0)
    try:
        if kind == "sphere":
            return SphereLight(center, fl.num("radius", gt=0), intensity)
        u, v = fl.vec("u"), fl.vec("v")
        if np.linalg.norm(np.cross(u, v)) <= 1e-9 * np.linalg.norm(u) * np.linalg.norm(v):
            fl.fail(f"[light].u x [light].v must have non-zero area, got u={u.tolist()}, v={v.tolist()}")
        return RectLight(center, u, v, intensity)
    except SceneError as exc:
        if str(exc).startswith(f"{file}: "):
            raise
        raise SceneError(f"{file}: [light]: {_strip(exc, 'light')}") from None


def _camera(file: str, table) -> Camera:
    fl = _Fields(file, table, "[camera]", _CAMERA_KEYS)
    eye, target = fl.vec("eye"), fl.vec("target")
    up = fl.vec("up", default=[0.0, 1.0, 0.0])
    fov = fl.num("fov_y", 45.0)
    if (why := fov_y_problem(fov)) is not None:  # the one rule, shared with Camera
        fl.fail(f"{fl.field('fov_y')} must be {why}, got {fov!r}")
    try:
        return Camera(eye, target, up, fov)
    except SceneError as exc:
        raise SceneError(f"{file}: [camera]: {_strip(exc, 'camera')}") from None


def load_toml(path) -> Scene:
    """Read a TOML scene file (format in the module docstring)."""
    path = Path(path)
    file = str(path)
    if not path.is_file():
        raise SceneError(f"{file}: file not found")
    try:
        raw = path.read_bytes()
        if raw.startswith(b"\xef\xbb\xbf"):  # a UTF-8 byte-order mark (Windows editors): accepted
            raw = raw[3:]
        doc = tomllib.loads(raw.decode("utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{file}: malformed TOML: {_one_line(exc)}") from None
    except UnicodeDecodeError as exc:
        raise SceneError(f"{file}: not UTF-8 text (TOML files are UTF-8): byte {exc.start}") from None
    except OSError as exc:
        raise SceneError(f"{file}: cannot read: {exc.strerror or _one_line(exc)}") from None
    top = _Fields(file, doc, "top level", _TOP_KEYS, sep=": ")
    name = top.string("name", path.stem)
    entries = doc.get("mesh")
    if entries is None:
        raise SceneError(f"{file}: no [[mesh]] entries")
    if not isinstance(entries, list) or not entries:
        raise SceneError(f"{file}: 'mesh' must be a list of [[mesh]] tables, got {_one_line(repr(entries))[:80]}")
    meshes = [_mesh_entry(file, path.parent, e, i + 1) for i, e in enumerate(entries)]
    allv = np.concatenate([m.vertices for m in meshes])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    if float(np.max(hi - lo)) <= 0:
        raise SceneError(f"{file}: the meshes have no extent")
    if "ground" in doc:
        g = doc["ground"]
        if g is True:
            g = {}
        if g is not False:
            if not isinstance(g, dict):
                raise SceneError(f"{file}: ground must be a table or true, got {g!r}")
            gf = _Fields(file, g, "ground", _GROUND_KEYS)
            meshes.append(
                _ground_mesh(
                    lo,
                    hi,
                    size=gf.num("size", None, gt=0),
                    y=gf.num("y", None),
                    albedo=gf.vec("albedo", default=[0.8, 0.8, 0.8], scalar_ok=True, ge=0, le=1),
                    cells=gf.num("cells", 8, integer=True, ge=1, le=1000),
                )
            )
    if "light" in doc:
        light = _light(file, doc["light"])
    else:
        olo, ohi = _occluder_bounds(meshes, lo, hi)
        light = _auto_light(olo, ohi)
    if "camera" in doc:
        camera = _camera(file, doc["camera"])
    else:
        olo, ohi = _occluder_bounds(meshes, lo, hi)
        ground_y = min((m.vertices[:, 1].min() for m in meshes if m.role == "receiver"), default=lo[1])
        camera = _auto_camera(olo, ohi, light, float(ground_y))
    return Scene(meshes, light, camera, name)


def _occluder_bounds(meshes, lo, hi):
    occ = [m.vertices for m in meshes if m.role != "receiver"]
    if not occ:
        return lo, hi
    v = np.concatenate(occ)
    return v.min(axis=0), v.max(axis=0)
