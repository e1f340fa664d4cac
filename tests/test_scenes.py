"""Scenes: primitives, built-in scenes, TOML scene files, mesh files, and their errors."""

import builtins
import math

import numpy as np
import pytest

from softshadows.errors import SceneError
from softshadows.scene import RectLight, SphereLight, builtin, load_scene
from softshadows.scene import primitives as prim
from softshadows.scene.builtin import BUILTIN


# ---- helpers ---------------------------------------------------------------------------------
def _signed_volume(v, f) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _in_frame(camera, points, aspect, margin=0.05) -> bool:
    """All points inside the central (1 - margin) of a pinhole image with this aspect (w/h)."""
    fwd = camera.target - camera.eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    q = np.asarray(points) - camera.eye
    z = q @ fwd
    t = math.tan(math.radians(camera.fov_y) / 2) * (1 - margin)
    return bool(np.all(z > 0) and np.all(np.abs(q @ right) <= t * aspect * z) and np.all(np.abs(q @ up) <= t * z))


def _write_obj(path, v, f):
    lines = [f"v {x} {y} {z}" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")
    return path


TETRA_V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])  # outward


def _err(fn, *args, **kw) -> str:
    with pytest.raises(SceneError) as ei:
        fn(*args, **kw)
    msg = str(ei.value)
    assert "\n" not in msg, msg
    return msg


# ---- primitives ------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", ["box", "icosphere", "cylinder"])
def test_closed_primitives_face_outward(shape):
    v, f = {
        "box": lambda: prim.box((1.0, 0.8, 0.6), (1, 2, 3)),
        "icosphere": lambda: prim.icosphere(0.5, (1, 2, 3), 2),
        "cylinder": lambda: prim.cylinder(0.2, (1, 2, 3), (1.5, 3, 3.2), 10),
    }[shape]()
    assert _signed_volume(v - v.mean(axis=0), f) > 0
    n = prim.face_normals(v, f)
    centroid = v[f].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", n, centroid - v.mean(axis=0)) > 0)


def test_box_and_sphere_volumes():
    v, f = prim.box((1.0, 0.8, 0.6))
    assert _signed_volume(v, f) == pytest.approx(0.48)
    v, f = prim.icosphere(1.0, (0, 0, 0), 3)
    assert len(f) == 1280 and _signed_volume(v, f) == pytest.approx(4 / 3 * np.pi, rel=0.02)


def test_plane_and_quad_normals():
    v, f = prim.plane(8, 6, 4, 3, y=0.5, center=(1, 0, 2))
    assert len(f) == 24
    assert np.allclose(prim.face_normals(v, f), [0, 1, 0])
    assert np.allclose(v.min(axis=0), [-3, 0.5, -1]) and np.allclose(v.max(axis=0), [5, 0.5, 5])
    v, f = prim.quad((0, 1, 0), (1, 0, 0), (0, 0, 1))
    assert np.allclose(prim.face_normals(v, f), [0, -1, 0])
    v, f = prim.ellipse_fans([[0, 0, 0]], [[1, 0, 0]], [[0.2, 1, 0]], [0.1], [0.05], 6)
    assert len(f) == 6 and np.all(prim.face_normals(v, f)[:, 1] > 0.9)


# ---- built-in scenes -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scenes():
    return {(n, s): load_scene(n, light=s) for n in BUILTIN for s in ("rect", "sphere")}


@pytest.mark.parametrize("name", list(BUILTIN))
def test_builtin_loads_with_both_lights_and_roles(scenes, name):
    rect, sph = scenes[(name, "rect")], scenes[(name, "sphere")]
    assert rect.name == sph.name == name
    assert isinstance(rect.light, RectLight) and isinstance(sph.light, SphereLight)
    assert np.allclose(rect.light.normal, [0, -1, 0])
    assert np.allclose(sph.light.center, rect.light.center)
    assert sph.light.area == pytest.approx(rect.light.area)
    assert 0.6 <= rect.light.size <= 1.0 and rect.light.center[1] >= 2.5
    ground = rect.meshes[0]
    assert ground.role == "receiver" and ground.name == "ground"
    assert np.allclose(ground.vertices[:, 1], 0.0) and np.allclose(ground.albedo, 0.8)
    assert np.allclose(prim.face_normals(ground.vertices, ground.faces), [0, 1, 0])
    objects = rect.meshes[1:]
    assert objects and all(m.role == "occluder" for m in objects)
    lo = np.concatenate([m.vertices for m in objects]).min(axis=0)
    assert lo[1] >= -1e-12  # nothing below the ground
    assert rect.has_roles


@pytest.mark.parametrize("name", list(BUILTIN))
def test_builtin_camera_frames_objects_and_whole_penumbra(scenes, name):
    s = scenes[(name, "rect")]
    occ = np.concatenate([m.vertices for m in s.meshes if m.role == "occluder"])
    pts = np.vstack([occ, builtin.shadow_footprint(s.light, occ, 0.0)])
    cam = s.camera
    fwd = (cam.target - cam.eye) / np.linalg.norm(cam.target - cam.eye)
    assert 30 <= np.degrees(np.arcsin(-fwd[1])) <= 45  # looking down 30-45 degrees
    for aspect in (1.0, 4 / 3):
        assert _in_frame(cam, pts, aspect, margin=0.1), (name, aspect)


def test_object_role_option():
    s = builtin.spheres(object_role="both")
    assert [m.role for m in s.meshes] == ["receiver", "both", "both", "both"]


def test_square_constants_match_geometry(scenes):
    s = scenes[("square", "rect")]
    occ = [m for m in s.meshes if m.role == "occluder"]
    assert len(occ) == 1 and len(occ[0].faces) == 2
    v = occ[0].vertices
    assert np.allclose(v[:, 1], builtin.SQUARE_OCCLUDER_Y)
    assert np.allclose(np.ptp(v, axis=0), [builtin.SQUARE_OCCLUDER_SIDE, 0, builtin.SQUARE_OCCLUDER_SIDE])
    assert np.allclose(v.mean(axis=0), [0, builtin.SQUARE_OCCLUDER_Y, 0])
    assert np.allclose(prim.face_normals(v, occ[0].faces), [0, 1, 0])  # facing the light
    lt = s.light
    assert np.allclose(lt.center, [0, builtin.SQUARE_LIGHT_Y, 0])
    assert np.allclose(lt.u, [builtin.SQUARE_LIGHT_SIDE, 0, 0]) and np.allclose(lt.v, [0, 0, builtin.SQUARE_LIGHT_SIDE])


def test_square_closed_form_against_monte_carlo():
    # umbra |x| <= 0.5, penumbra to 1.0 (light 1 at y=3, occluder 1 at y=1)
    v = builtin.square_visibility([[0, 0, 0], [0.5, 0, 0], [0.75, 0, 0], [1.0, 0, 0], [2, 0, 0], [0.75, 0, 0.75]])
    assert np.allclose(v, [0, 0, 0.5, 1, 1, 0.75])
    rng = np.random.default_rng(0)
    p = np.array([[0.62, 0.0, -0.81], [0.3, 0.4, 0.2], [-0.9, 0.0, 0.55]])
    s = rng.uniform(-0.5, 0.5, (200_000, 2)) * builtin.SQUARE_LIGHT_SIDE
    L = np.stack([s[:, 0], np.full(len(s), builtin.SQUARE_LIGHT_Y), s[:, 1]], 1)
    for pt, ref in zip(p, builtin.square_visibility(p)):
        t = (builtin.SQUARE_OCCLUDER_Y - pt[1]) / (L[:, 1] - pt[1])
        hit = pt + (L - pt) * t[:, None]
        blocked = (np.abs(hit[:, 0]) <= 0.5) & (np.abs(hit[:, 2]) <= 0.5)
        assert 1 - blocked.mean() == pytest.approx(ref, abs=0.005)


def test_plant_is_big_and_deterministic(scenes):
    s = scenes[("plant", "rect")]
    n = sum(len(m.faces) for m in s.meshes if m.role == "occluder")
    assert n >= 20_000
    occ = np.concatenate([m.vertices for m in s.meshes if m.role == "occluder"])
    assert 1.3 <= occ[:, 1].max() <= 1.8
    again = builtin.plant()
    assert all(np.array_equal(a.vertices, b.vertices) for a, b in zip(s.meshes, again.meshes))


def test_bunny_is_shipped_decimated_and_does_not_read_shared(monkeypatch):
    real_open = builtins.open
    opened = []

    def guarded_open(file, *a, **kw):
        opened.append(str(file))
        assert "shared" not in str(file), file
        return real_open(file, *a, **kw)

    monkeypatch.setattr(builtins, "open", guarded_open)
    builtin._bunny_arrays.cache_clear()
    s = load_scene("bunny")
    bunny = [m for m in s.meshes if m.role == "occluder"]
    assert len(bunny) == 1 and 8_000 <= len(bunny[0].faces) <= 12_000
    v = bunny[0].vertices
    assert v[:, 1].min() == pytest.approx(0.0, abs=1e-6) and v[:, 1].max() == pytest.approx(1.2, rel=0.01)
    assert abs(v[:, 0].min() + v[:, 0].max()) < 1e-3 and abs(v[:, 2].min() + v[:, 2].max()) < 1e-3
    assert _signed_volume(v, bunny[0].faces) > 0


def test_bunny_data_file_is_small_and_attributed():
    from importlib import resources

    data = resources.files("softshadows").joinpath("data")
    raw = data.joinpath("bunny.npz").read_bytes()
    assert len(raw) < 300_000
    text = data.joinpath("ATTRIBUTION.md").read_text()
    assert "Stanford" in text and "Turk" in text and "Levoy" in text


def test_builtin_scenes_listing():
    from softshadows.scene import builtin_scenes

    d = builtin_scenes()
    assert set(d) == {"square", "spheres", "fence", "contact", "plant", "bunny"}
    assert all(isinstance(x, str) and x for x in d.values())


# ---- TOML scene files ------------------------------------------------------------------------
def test_toml_round_trip_with_transform(tmp_path):
    (tmp_path / "models").mkdir()
    _write_obj(tmp_path / "models" / "tet.obj", TETRA_V, TETRA_F)
    (tmp_path / "scene.toml").write_text("""
name = "tet scene"
ground = { size = 6, albedo = [0.5, 0.5, 0.5] }
[camera]
eye = [0, 3, 6]
target = [0, 0, 0]
fov_y = 50
[light]
type = "rect"
center = [0, 4, 0]
u = [0.5, 0, 0]
v = [0, 0, 0.5]
intensity = 2.0
[[mesh]]
path = "models/tet.obj"
albedo = [0.8, 0.7, 0.6]
role = "occluder"
translate = [1, 2, 3]
rotate = [0, 90, 0]
scale = 2.0
[[mesh]]
primitive = "box"
size = [1, 2, 3]
center = [0, 1, 0]
matrix = [[1, 0, 0, 5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
""")
    s = load_scene(tmp_path / "scene.toml")
    assert s.name == "tet scene"
    tet, box, ground = s.meshes
    # scale 2, rotate +90 about y: (x, y, z) -> (z, y, -x), then translate
    exp = np.stack([2 * TETRA_V[:, 2], 2 * TETRA_V[:, 1], -2 * TETRA_V[:, 0]], 1) + [1, 2, 3]
    assert np.allclose(tet.vertices, exp)
    assert tet.role == "occluder" and tet.albedo == (0.8, 0.7, 0.6) and tet.name == "tet"
    assert _signed_volume(tet.vertices, tet.faces) > 0
    assert np.allclose(box.vertices.min(axis=0), [4.5, 0, -1.5]) and box.role == "both"
    assert ground.role == "receiver" and np.allclose(ground.vertices[:, 1], 0.0)
    assert np.ptp(ground.vertices[:, 0]) == pytest.approx(6) and ground.albedo == (0.5, 0.5, 0.5)
    assert isinstance(s.light, RectLight) and s.light.intensity == 2.0 and s.light.area == pytest.approx(0.25)
    assert s.camera.fov_y == 50 and np.allclose(s.camera.eye, [0, 3, 6])
    sph = load_scene(tmp_path / "scene.toml", light="sphere")
    assert isinstance(sph.light, SphereLight) and sph.light.area == pytest.approx(0.25)


def test_toml_sphere_light_defaults_and_mirroring(tmp_path):
    (tmp_path / "s.toml").write_text("""
[light]
type = "sphere"
center = [0, 5, 0]
radius = 0.3
[[mesh]]
primitive = "sphere"
radius = 0.5
center = [0, 1, 0]
subdivisions = 1
scale = [-1, 1, 1]
""")
    s = load_scene(str(tmp_path / "s.toml"))
    assert s.name == "s" and isinstance(s.light, SphereLight) and s.light.radius == 0.3
    assert _signed_volume(s.meshes[0].vertices - [0, 1, 0], s.meshes[0].faces) > 0  # mirrored, still outward
    r = load_scene(tmp_path / "s.toml", light="rect")
    assert isinstance(r.light, RectLight) and r.light.area == pytest.approx(np.pi * 0.09)
    assert np.allclose(r.light.normal, [0, -1, 0])
    fwd = s.camera.target - s.camera.eye  # automatic camera looks at the mesh
    assert fwd[1] < 0


def _toml(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


MESH_OK = '[[mesh]]\nprimitive = "box"\n'
LIGHT_OK = "[light]\ncenter = [0, 4, 0]\nu = [1, 0, 0]\nv = [0, 0, 1]\n"


@pytest.mark.parametrize(
    "text, needles",
    [
        (LIGHT_OK + '[[mesh]]\npath = "missing.obj"\n', ["[[mesh]] #1", "path 'missing.obj' not found"]),
        ("[light\ncenter = 1\n", ["malformed TOML", "line"]),
        ("[light]\ncenter = [0, 4, 0]\nu = [1, 0, 0]\nv = [2, 0, 0]\n" + MESH_OK, ["[light].u", "area"]),
        (
            '[light]\ntype = "sphere"\ncenter = [0, 4, 0]\nradius = -1\n' + MESH_OK,
            ["[light].radius must be > 0, got -1"],
        ),
        (LIGHT_OK + "colour = 3\n" + MESH_OK, ["[light]", "unknown key 'colour'"]),
        (LIGHT_OK + MESH_OK + 'role = "shadow"\n', ["[[mesh]] #1", "role", "shadow", "occluder"]),
        (LIGHT_OK + MESH_OK + MESH_OK + "sise = 2\n", ["[[mesh]] #2", "unknown key 'sise'"]),
        (LIGHT_OK + MESH_OK + "albedo = [1, 2]\n", ["[[mesh]] #1", "albedo"]),
        (
            LIGHT_OK + MESH_OK + "translate = [1, 2, 3]\nmatrix = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n",
            ["matrix", "translate"],
        ),
        (LIGHT_OK + MESH_OK + "scale = 0\n", ["[[mesh]] #1", "scale", "got 0"]),
        (LIGHT_OK + '[[mesh]]\nprimitive = "torus"\n', ["primitive", "torus"]),
        (LIGHT_OK + "[[mesh]]\nalbedo = 0.5\n", ["[[mesh]] #1", "path", "primitive"]),
        (LIGHT_OK, ["no [[mesh]]"]),
        ("[camera]\neye = [0, 1, 0]\ntarget = [0, 1, 0]\n" + MESH_OK, ["[camera]: eye and target coincide"]),
        ("[camera]\neye = [0, 1]\ntarget = [0, 0, 0]\n" + MESH_OK, ["[camera].eye", "3 numbers"]),
        ("mystery = 1\n" + MESH_OK, ["unknown key 'mystery'"]),
    ],
)
def test_toml_errors_name_file_and_field(tmp_path, text, needles):
    p = _toml(tmp_path, text)
    msg = _err(load_scene, p)
    assert msg.startswith(str(p)), msg
    for n in needles:
        assert n in msg, (n, msg)


def test_nan_vertex_in_obj(tmp_path):
    obj = tmp_path / "bad.obj"
    obj.write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    msg = _err(load_scene, obj)
    assert "bad.obj" in msg and "vertex 1" in msg and "finite" in msg
    p = _toml(tmp_path, LIGHT_OK + '[[mesh]]\npath = "bad.obj"\n')
    msg = _err(load_scene, p)
    assert "scene.toml" in msg and "[[mesh]] #1" in msg and "vertex 1" in msg


def test_mesh_file_errors(tmp_path):
    assert "file not found" in _err(load_scene, tmp_path / "nope.obj")
    assert "nope.toml" in _err(load_scene, tmp_path / "nope.toml")
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    assert "no triangles" in _err(load_scene, tmp_path / "points.obj")
    (tmp_path / "x.xyz").write_text("1 2 3\n")
    assert "unsupported" in _err(load_scene, tmp_path / "x.xyz")


def test_unknown_builtin_lists_the_builtins():
    msg = _err(load_scene, "teapot-of-doom")
    assert "teapot-of-doom" in msg and all(n in msg for n in BUILTIN)
    assert "light" in _err(load_scene, "square", light="disk")


# ---- a mesh file alone -----------------------------------------------------------------------
def test_mesh_file_alone_is_staged(tmp_path):
    v = TETRA_V * 2.0 + [10, 5, -3]  # keeps its units and position
    s = load_scene(_write_obj(tmp_path / "tet.obj", v, TETRA_F))
    assert s.name == "tet"
    obj = [m for m in s.meshes if m.role == "occluder"]
    ground = [m for m in s.meshes if m.role == "receiver"]
    assert len(obj) == 1 and len(ground) == 1
    assert np.allclose(obj[0].vertices, v)
    assert np.allclose(ground[0].vertices[:, 1], 5.0)  # at the object's lowest y
    assert np.ptp(ground[0].vertices[:, 0]) == pytest.approx(8.0)  # 4x the extent
    lt = s.light
    assert isinstance(lt, RectLight) and np.allclose(lt.normal, [0, -1, 0])
    assert lt.center[1] == pytest.approx(7.0 + 4.0) and lt.size == pytest.approx(1.0)
    center = (v.min(axis=0) + v.max(axis=0)) / 2
    fwd = (s.camera.target - s.camera.eye) / np.linalg.norm(s.camera.target - s.camera.eye)
    to_obj = (center - s.camera.eye) / np.linalg.norm(center - s.camera.eye)
    assert fwd @ to_obj > 0.95 and fwd[1] < -0.3
    assert _in_frame(s.camera, np.vstack([v, builtin.shadow_footprint(lt, v, 5.0)]), 1.0)
    sph = load_scene(tmp_path / "tet.obj", light="sphere")
    assert isinstance(sph.light, SphereLight) and sph.light.area == pytest.approx(lt.area)


def test_multi_part_file_is_flattened_with_transforms(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    sc = trimesh.Scene()
    sc.add_geometry(
        trimesh.Trimesh(TETRA_V, TETRA_F, process=False),
        transform=trimesh.transformations.translation_matrix([0, 3, 0]),
    )
    sc.add_geometry(trimesh.Trimesh(TETRA_V, TETRA_F, process=False))
    sc.export(tmp_path / "two.glb")
    s = load_scene(tmp_path / "two.glb")
    obj = next(m for m in s.meshes if m.role == "occluder")
    assert len(obj.faces) == 8 and obj.vertices[:, 1].max() == pytest.approx(4.0)


def test_real_obj_model_loads_every_face(test_models):
    path = test_models / "suzanne.obj"
    # polygons are fanned into triangles: an n-gon gives n - 2
    n_faces = sum(len(line.split()) - 3 for line in path.read_text().splitlines() if line.startswith("f "))
    s = load_scene(path, light="sphere")
    assert sum(len(m.faces) for m in s.meshes if m.role == "occluder") == n_faces


def test_docstring_example_loads(tmp_path):
    from softshadows.scene import loaders

    doc = loaders.__doc__
    block = doc[doc.index("shown; the comments say which are optional)::") :].split("\n\n\n")[0]
    text = "\n".join(line[4:] for line in block.splitlines()[1:])
    (tmp_path / "models").mkdir()
    _write_obj(tmp_path / "models" / "bunny.obj", TETRA_V * 0.15, TETRA_F)
    s = load_scene(_toml(tmp_path, text))
    assert s.name == "bunny on a table" and [m.name for m in s.meshes] == ["bunny", "box #2", "ground"]
    assert [m.role for m in s.meshes] == ["occluder", "both", "receiver"]


def test_rect_light_normal_and_area_are_numpys_cross_bit_for_bit():
    """``RectLight.normal`` / ``area`` compute u x v with scalar arithmetic (``geometry.vectors.cross3``, faster than
    ``np.cross`` on 3-vectors): the same bits as ``np.cross`` over lights of every scale."""
    rng = np.random.default_rng(11)
    for _ in range(2000):
        s = 10.0 ** rng.uniform(-6, 6)
        u, v = rng.normal(size=3) * s, rng.normal(size=3) * s
        light = RectLight(rng.normal(size=3), u, v)
        n = np.cross(u, v)
        assert np.array_equal(light.normal, n / np.linalg.norm(n))
        assert light.area == float(np.linalg.norm(n))
