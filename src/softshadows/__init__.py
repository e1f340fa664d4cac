"""softshadows: soft shadows from area lights, classic algorithms beside a ray-traced ground truth.

Every method computes V, the visible fraction of the light at each eye pixel, behind one interface::

    import softshadows as ss
    scene = ss.load_scene("bunny", light="sphere")
    res = ss.render(scene, "penumbra-map", 512, 512)
    res.visibility, res.image, res.timings, res.stats
"""

from ._malloc import tune_malloc
from .api import Result, render
from .errors import SceneError, SoftShadowsError
from .scene import Camera, Mesh, RectLight, Scene, SphereLight


def load_scene(name_or_path, light=None):
    """A built-in scene name, a TOML scene file or a mesh file; ``light='rect'|'sphere'`` swaps the light."""
    from .scene.loaders import load_scene as _load

    return _load(name_or_path, light=light)


def methods() -> dict:
    """Registered methods by name (each with ``params``, ``light_shapes``, ``summary``)."""
    from .methods import methods as _methods

    return _methods()


__all__ = [
    "Camera",
    "Mesh",
    "RectLight",
    "Result",
    "Scene",
    "SceneError",
    "SoftShadowsError",
    "SphereLight",
    "load_scene",
    "methods",
    "render",
    "tune_malloc",
]
__version__ = "0.1.0"
