"""Area-uniform samples of a triangle surface, with the face each one lies on (trimesh)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io.values import mesh_arrays

__all__ = ["SurfaceSamples", "sample_surface"]


@dataclass(frozen=True)
class SurfaceSamples:
    """Area-uniform samples of a surface.

    Attributes
    ----------
    points : (n, 3) float
    face_index : (n,) int
        The face each sample lies on (for voxel inputs: the face of the voxel boundary mesh).
    """

    points: np.ndarray
    face_index: np.ndarray


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int = 10000, seed=None) -> SurfaceSamples:
    """Draw ``count`` points uniformly by area on the triangle mesh, with their face ids."""
    import trimesh

    vertices, faces = mesh_arrays(vertices, faces, empty=False)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    points, face_index = trimesh.sample.sample_surface(mesh, count, seed=np.random.default_rng(seed))
    return SurfaceSamples(np.asarray(points, np.float64), np.asarray(face_index, np.int64))
