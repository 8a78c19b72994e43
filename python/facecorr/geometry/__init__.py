"""Geometry on triangle meshes and point sets (floor 1: imports only the Rust core and the base).

``mesh`` (:class:`Mesh`, millimetres, cached normals / areas / edges / boundary / components /
KD-tree), ``spatial`` (KD-tree, voxel subsampling), ``geodesic`` (fast marching, Dijkstra),
``descriptors`` (Finger Print), ``curvature`` (principal curvatures, umbilics), ``roughness``
(per-vertex surface roughness), ``raster`` (depth rasterizer) and ``transforms`` (the one
Kabsch/Umeyama, rotations).
"""

from . import curvature, descriptors, geodesic, raster, roughness, spatial, transforms
from .mesh import Mesh

__all__ = ["Mesh", "curvature", "descriptors", "geodesic", "raster", "roughness", "spatial", "transforms"]
