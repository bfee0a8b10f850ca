"""Triangle meshes with a class code, an instance id and a material per triangle.

Scenes are assembled from simple primitives (height fields, boxes, cylinders, leaf clouds)
by :class:`MeshBuilder`; every primitive carries the label code of ``prc_slam.labels`` and
an instance id, so every ray hit has its ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Materials: how a surface answers a LiDAR pulse (see :mod:`data_tools.sim.noise`).
SOLID, GLASS, FOLIAGE, DARK = 0, 1, 2, 3


@dataclass
class Mesh:
    """A triangle soup with per-triangle attributes.

    Attributes
    ----------
    vertices : float32 (V, 3)
    triangles : int32 (T, 3)
    label : uint8 (T,)
        Class code per triangle.
    instance : uint32 (T,)
    material : uint8 (T,)
    reflectivity : float32 (T,)
        Diffuse reflectivity in [0, 1] (intensity and low-reflectivity dropouts).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    label: np.ndarray
    instance: np.ndarray
    material: np.ndarray
    reflectivity: np.ndarray

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    def subset(self, mask: np.ndarray) -> Mesh:
        """The triangles selected by ``mask`` (vertices shared, not compacted)."""
        return Mesh(
            self.vertices,
            self.triangles[mask],
            self.label[mask],
            self.instance[mask],
            self.material[mask],
            self.reflectivity[mask],
        )


class MeshBuilder:
    """Accumulates primitives into one :class:`Mesh`."""

    def __init__(self) -> None:
        self._v: list[np.ndarray] = []
        self._t: list[np.ndarray] = []
        self._attr: list[tuple[int, int, int, float, int]] = []
        self._nv = 0
        self.next_instance = 1

    def new_instance(self) -> int:
        """A fresh instance id."""
        self.next_instance += 1
        return self.next_instance - 1

    def add(
        self,
        vertices: np.ndarray,
        triangles: np.ndarray,
        label: int,
        instance: int = 0,
        material: int = SOLID,
        reflectivity: float = 0.5,
    ) -> None:
        """Add triangles (indices into ``vertices``) with one set of attributes."""
        vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        if len(triangles) == 0:
            return
        self._v.append(vertices)
        self._t.append(triangles + self._nv)
        self._attr.append((label, instance, material, reflectivity, len(triangles)))
        self._nv += len(vertices)

    def build(self) -> Mesh:
        """Concatenate everything added so far."""
        if not self._t:
            z = np.zeros((0, 3))
            return Mesh(
                z.astype(np.float32),
                z.astype(np.int32),
                *(np.zeros(0, d) for d in (np.uint8, np.uint32, np.uint8, np.float32)),
            )
        counts = [a[4] for a in self._attr]
        return Mesh(
            np.concatenate(self._v).astype(np.float32),
            np.concatenate(self._t).astype(np.int32),
            np.repeat([a[0] for a in self._attr], counts).astype(np.uint8),
            np.repeat([a[1] for a in self._attr], counts).astype(np.uint32),
            np.repeat([a[2] for a in self._attr], counts).astype(np.uint8),
            np.repeat([a[3] for a in self._attr], counts).astype(np.float32),
        )

    # ---- primitives -------------------------------------------------------------------

    def grid(self, xyz: np.ndarray, label: int, **attrs: object) -> None:
        """A surface from a ``(n, m, 3)`` grid of vertices (two triangles per cell)."""
        n, m, _ = xyz.shape
        idx = np.arange(n * m).reshape(n, m)
        a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
        tris = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
        self.add(xyz.reshape(-1, 3), tris, label, **attrs)

    def quad(self, p0, p1, p2, p3, label: int, **attrs: object) -> None:
        """A planar quadrilateral ``p0 p1 p2 p3`` (counter-clockwise)."""
        self.add(np.array([p0, p1, p2, p3]), np.array([[0, 1, 2], [0, 2, 3]]), label, **attrs)

    def box(self, center, size, yaw: float, label: int, *, faces: tuple[str, ...] = ("all",), **attrs: object) -> None:
        """An oriented box (``size`` = length, width, height; ``center`` at the box's base
        centre; rotated by ``yaw`` about z). ``faces`` selects sides: ``+x -x +y -y top bottom``."""
        lx, ly, lz = np.asarray(size, float) / np.array([2, 2, 1])
        corners = np.array([[sx * lx, sy * ly, sz * lz] for sz in (0, 1) for sy in (-1, 1) for sx in (-1, 1)])
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        v = corners @ rot.T + np.asarray(center, float)
        sides = {
            "bottom": [[0, 2, 3], [0, 3, 1]],
            "top": [[4, 5, 7], [4, 7, 6]],
            "-y": [[0, 1, 5], [0, 5, 4]],
            "+y": [[2, 6, 7], [2, 7, 3]],
            "-x": [[0, 4, 6], [0, 6, 2]],
            "+x": [[1, 3, 7], [1, 7, 5]],
        }
        names = sides.keys() if "all" in faces else faces
        self.add(v, np.array([t for name in names for t in sides[name]]), label, **attrs)

    def cylinder(
        self,
        base,
        axis,
        radius: float,
        height: float,
        label: int,
        *,
        segments: int = 12,
        cap: bool = True,
        **attrs: object,
    ) -> None:
        """A cylinder from ``base`` along unit ``axis`` (leaning stems, poles, wheels)."""
        axis = np.asarray(axis, float)
        axis = axis / np.linalg.norm(axis)
        helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
        u = np.cross(axis, helper)
        u /= np.linalg.norm(u)
        w = np.cross(axis, u)
        ang = 2 * np.pi * np.arange(segments) / segments
        ring = radius * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * w)
        base = np.asarray(base, float)
        v = np.concatenate([base + ring, base + height * axis + ring, [base, base + height * axis]])
        i = np.arange(segments)
        j = (i + 1) % segments
        tris = [np.stack([i, j, j + segments], 1), np.stack([i, j + segments, i + segments], 1)]
        if cap:
            tris += [
                np.stack([np.full(segments, 2 * segments), j, i], 1),
                np.stack([np.full(segments, 2 * segments + 1), i + segments, j + segments], 1),
            ]
        self.add(v, np.concatenate(tris), label, **attrs)

    def leaf_cloud(
        self, rng: np.random.Generator, center, radii, count: int, leaf_size: float, label: int, **attrs: object
    ) -> None:
        """``count`` small randomly oriented triangles filling an ellipsoid: a porous crown,
        bush or hedge through which some rays pass."""
        u = rng.normal(size=(count, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        rad = rng.random(count) ** (1 / 3)
        centres = np.asarray(center, float) + u * rad[:, None] * np.asarray(radii, float)
        offs = rng.normal(size=(count, 3, 3)) * leaf_size
        v = (centres[:, None, :] + offs).reshape(-1, 3)
        self.add(v, np.arange(3 * count).reshape(-1, 3), label, material=FOLIAGE, **attrs)
