"""Shared geometric queries on triangle meshes (silhouettes, adjacency) used by several methods."""

from .silhouette import (
    EdgeAdjacency,
    Silhouette,
    build_adjacency,
    facing,
    find_silhouette,
    silhouette_adjacency,
    silhouette_brute,
    weld_vertices,
)

__all__ = [
    "EdgeAdjacency",
    "Silhouette",
    "build_adjacency",
    "facing",
    "find_silhouette",
    "silhouette_adjacency",
    "silhouette_brute",
    "weld_vertices",
]
