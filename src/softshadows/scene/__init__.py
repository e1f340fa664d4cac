"""Scenes: meshes with roles, area lights, a camera; built-in scenes and loaders."""

from .builtin import BUILTIN, builtin_scenes, frame_camera, with_light_shape
from .loaders import load_scene
from .types import Camera, FlatGeometry, Mesh, RectLight, Scene, SphereLight, rect_to_sphere, sphere_to_rect

__all__ = [
    "BUILTIN",
    "Camera",
    "FlatGeometry",
    "Mesh",
    "RectLight",
    "Scene",
    "SphereLight",
    "builtin_scenes",
    "frame_camera",
    "load_scene",
    "rect_to_sphere",
    "sphere_to_rect",
    "with_light_shape",
]
