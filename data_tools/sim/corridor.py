"""A corridor (road tunnel) scene: the case in which scan matching cannot see the motion.

A straight tunnel along world x: flat ground, two uniform vertical walls and a ceiling. Only its
first ``structured`` metres hold cross-structure (a closed back wall, buttresses standing out
of the walls, beams under the ceiling); beyond them every surface is invariant under a
translation along the axis, so a registration of the walls, ground and ceiling constrains the
lateral position, height, roll, pitch and yaw but not the position along the tunnel. The
surfaces carry only millimetre roughness, far below any registration's voxel. A vehicle drives
through without stopping (``Simulator``): a change of speed in the featureless stretch cannot be
seen by any registration, only carried on by a motion model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from data_tools.sim.mesh import MeshBuilder
from data_tools.sim.scenes import Centerline, Scene
from prc_slam import labels as L

#: the corridor's axis in the world frame
AXIS = np.array([1.0, 0.0, 0.0])


@dataclass
class CorridorParams:
    """Dimensions of the tunnel (metres)."""

    length: float = 400.0
    half_width: float = 4.5
    height: float = 5.5
    structured: float = 60.0  # the entrance: back wall, buttresses and beams up to here
    buttress_spacing: float = 5.0
    roughness: float = 0.003  # std of the surfaces' relief


def corridor_tunnel(seed: int = 0, params: CorridorParams | None = None) -> Scene:
    """A straight road tunnel along +x from x = 0 (the closed back wall at x = -15) to
    ``params.length``; cross-structure only before ``params.structured``.

    Parameters
    ----------
    seed : int
        Seed of the surfaces' roughness and of the entrance's layout.
    params : CorridorParams, optional

    Returns
    -------
    Scene
        ``kind="corridor"``; the centreline runs along the axis at the road's height (0);
        ``info`` holds ``axis`` (world unit vector) and ``structured_until`` (x, m).
    """
    p = params or CorridorParams()
    rng = np.random.default_rng(seed)
    b = MeshBuilder()
    x0, x1 = -15.0, p.length + 5.0
    xs = np.arange(x0, x1 + 1e-9, 1.0)
    W, H = p.half_width, p.height

    def rough(shape: tuple[int, ...]) -> np.ndarray:
        return rng.normal(0.0, p.roughness, shape)

    # ground: flat road across the tunnel
    ys = np.linspace(-W, W, 19)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    b.grid(np.dstack([X, Y, rough(X.shape)]), L.GROUND, reflectivity=0.25)
    # walls and ceiling: uniform along the axis
    zs = np.linspace(0.0, H, 12)
    for side in (-1.0, 1.0):
        X, Z = np.meshgrid(xs, zs, indexing="ij")
        Y = side * W + rough(X.shape)
        b.grid(np.dstack([X, Y, Z]), L.BUILDING, reflectivity=0.5)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    b.grid(np.dstack([X, Y, H + rough(X.shape)]), L.BUILDING, reflectivity=0.5)
    # the entrance: back wall, buttresses on both walls, beams under the ceiling
    b.quad([x0, -W, 0.0], [x0, W, 0.0], [x0, W, H], [x0, -W, H], L.BUILDING, reflectivity=0.5)
    x = rng.uniform(0.0, 2.0)
    while x < p.structured:
        for side in (-1.0, 1.0):  # buttresses standing out of both walls, at irregular spacing
            depth = rng.uniform(0.8, 1.5)
            b.box([x + rng.uniform(-1, 1), side * (W - depth / 2), 0.0], (rng.uniform(0.6, 1.2), depth, H), 0.0,
                  L.BUILDING, instance=b.new_instance())  # fmt: skip
        if rng.random() < 0.5:  # a beam under the ceiling
            b.box([x + 2.0, 0.0, H - 0.8], (0.6, 2 * W, 0.8), 0.0, L.BUILDING, faces=("+x", "-x", "bottom"))
        x += p.buttress_spacing * rng.uniform(0.6, 1.4)
    axis_xy = np.arange(0.0, p.length + 1e-9, 0.5)
    centre = Centerline(np.column_stack([axis_xy, np.zeros_like(axis_xy)]), np.zeros(len(axis_xy)),
                        np.zeros(len(axis_xy)), 0.5)  # fmt: skip
    return Scene(b.build(), "corridor", seed, centre, {"axis": AXIS.tolist(), "structured_until": p.structured})


def featureless(positions: np.ndarray, scene_info: dict, reach: float) -> np.ndarray:
    """Which sensor positions see no cross-structure within ``reach`` metres.

    Parameters
    ----------
    positions : float (n, 3)
        Sensor positions in the world frame.
    scene_info : dict
        The corridor scene's ``info`` (``structured_until``).
    reach : float
        The farthest range that can show the entrance (the sensor's or the odometry's maximum
        range).

    Returns
    -------
    bool (n,)
    """
    return np.asarray(positions)[:, 0] > float(scene_info["structured_until"]) + reach


__all__ = ["AXIS", "CorridorParams", "corridor_tunnel", "featureless"]
