"""The corridor (tunnel) scene: cross-structure only at the entrance, uniform walls beyond, and
the simulator renders it from a vehicle that does not stop."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from data_tools.sim.corridor import CorridorParams, corridor_tunnel, featureless
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam import labels as L


def face_normals(scene) -> tuple[np.ndarray, np.ndarray]:
    v = scene.mesh.vertices[scene.mesh.triangles].astype(np.float64)
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area = np.linalg.norm(n, axis=1)
    keep = area > 1e-9
    return n[keep] / area[keep, None], v[keep].mean(axis=1)


def test_no_surface_faces_the_axis_beyond_the_entrance():
    params = CorridorParams(length=200.0)
    scene = corridor_tunnel(3, params)
    normals, centres = face_normals(scene)
    across = np.abs(normals[:, 0]) > 0.5  # a face that would show a motion along the tunnel
    assert across.any()  # the entrance has some
    assert centres[across, 0].max() < params.structured + 3.0
    # beyond it: ground, two walls and a ceiling, each flat to the roughness
    beyond = centres[:, 0] > params.structured + 3.0
    assert np.abs(normals[beyond, 0]).max() < 0.05
    assert scene.info["structured_until"] == params.structured
    assert set(np.unique(scene.mesh.label)) == {L.GROUND, L.BUILDING}


def test_featureless_positions():
    info = {"structured_until": 60.0}
    pos = np.array([[100.0, 0, 0], [160.5, 0, 0], [300.0, 0, 0]])
    assert featureless(pos, info, 100.0).tolist() == [False, True, True]


def test_simulator_renders_the_corridor_from_a_vehicle_without_stops():
    sim = Simulator(SimConfig(scene="corridor", sensor="hdl64", frames=40, seed=1))
    assert sim.scene.kind == "corridor" and sim.trajectory.kind == "vehicle"
    speed = np.linalg.norm(np.diff(sim.trajectory.position[:, :2], axis=0), axis=1) * 200.0
    assert speed[400:].min() > 8.0  # cruising at 8.33 m/s after the start, no stop
    frame = sim.frame(0)
    hit = frame.ranges > 0
    assert hit.mean() > 0.5  # a closed tunnel: most rays return
    assert {L.GROUND, L.BUILDING} <= set(np.unique(frame.labels[hit]).tolist())


def test_unknown_scene_is_refused():
    with pytest.raises(ValidationError):
        SimConfig(scene="canyon")
