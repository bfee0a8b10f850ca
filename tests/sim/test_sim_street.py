"""The parked-car street (``simulate --scene street``): vehicles of every kind, near and far, both
sides, angled and occluded, and vehicles that drive between sweeps."""

from __future__ import annotations

import numpy as np
import pytest

from data_tools.sim.simulator import SimConfig, Simulator
from data_tools.sim.street import StreetScene, street_scene
from prc_slam import labels as L


@pytest.fixture(scope="module")
def scene() -> StreetScene:
    return street_scene(3)


def vehicle_centres(scene: StreetScene) -> dict[int, np.ndarray]:
    mesh = scene.mesh
    veh = mesh.label == L.VEHICLE
    out = {}
    for k in np.unique(mesh.instance[veh]):
        v = mesh.vertices[np.unique(mesh.triangles[veh & (mesh.instance == k)])]
        out[int(k)] = np.r_[v.mean(axis=0)[:2], v[:, 2].max() - v[:, 2].min(), np.ptp(v[:, 0]), np.ptp(v[:, 1])]
    return out


def test_vehicles_of_every_kind_on_both_sides(scene):
    info = scene.info
    assert info["cars"] >= 30 and info["trucks"] == 1 and info["angled"] >= 4 and info["moving_cars"] == 4
    cars = vehicle_centres(scene)
    assert len(cars) == info["cars"]
    heights = np.array([c[2] for c in cars.values()])
    assert heights.max() > 2.9  # the truck
    assert ((heights > 1.9) & (heights < 2.5)).any()  # vans
    assert ((heights > 1.6) & (heights < 1.9)).any()  # SUVs
    assert (heights < 1.6).sum() >= 10  # cars
    # both sides of the centreline (a straight start along +x: y is the lateral offset)
    near_start = [c for c in cars.values() if c[0] < 80]
    assert any(c[1] > 3 for c in near_start) and any(c[1] < -3 for c in near_start)


def test_scene_is_deterministic_and_seeds_differ():
    a, b, c = street_scene(5), street_scene(5), street_scene(6)
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    assert a.mesh.vertices.shape != c.mesh.vertices.shape or not np.array_equal(a.mesh.vertices, c.mesh.vertices)


def test_movers_move_and_nothing_else(scene):
    mesh = scene.mesh
    v0 = mesh.vertices.astype(np.float64)
    v1 = scene.move(v0, 1.0)
    moved = np.linalg.norm(v1 - v0, axis=1) > 1e-9
    moving = np.zeros(len(v0), bool)
    moving[np.unique(mesh.triangles[scene.moving_triangles()])] = True
    assert moved.any() and not (moved & ~moving).any()
    np.testing.assert_allclose(scene.move(v0, 0.0), v0, atol=1e-4)
    for m in scene.movers:  # each travels its speed along the street in one second, staying rigid
        vids = np.unique(mesh.triangles[(mesh.instance == m.instance) & (mesh.label == L.VEHICLE)])
        shift = np.linalg.norm((v1[vids] - v0[vids]).mean(axis=0)[:2])
        assert shift == pytest.approx(m.speed, rel=0.05)
        d0 = np.linalg.norm(v0[vids[1:]] - v0[vids[0]], axis=1)
        d1 = np.linalg.norm(v1[vids[1:]] - v1[vids[0]], axis=1)
        np.testing.assert_allclose(d1, d0, atol=1e-6)


def test_simulated_street_sees_vehicles_near_and_far_and_moving():
    sim = Simulator(SimConfig(scene="street", sensor="os1-64", frames=2, seed=3))
    frames = [sim.frame(i) for i in range(2)]
    xyz = sim.sensor.model.to_xyz(frames[0].ranges)
    veh = frames[0].labels == L.VEHICLE
    dist = []
    for k in np.unique(frames[0].instance[veh]):
        m = veh & (frames[0].instance == k)
        if m.sum() >= 20:
            dist.append(float(np.hypot(*xyz[m][:, :2].mean(axis=0))))
    dist = np.array(dist)
    assert (dist < 5).any() and ((dist > 20) & (dist < 40)).any()
    # a driving vehicle's returns move between sweeps relative to the world more than the parked ones
    movers = {m.instance for m in sim.scene.movers}
    seen = [k for k in movers if ((frames[0].instance == k) & (frames[0].labels == L.VEHICLE)).sum() >= 20]
    assert seen
    assert sim.scene.info["walk_lateral"] < -6.5  # a walker keeps to the right sidewalk


def test_street_is_a_config_choice():
    assert SimConfig(scene="street").scene == "street"
    with pytest.raises(ValueError):
        SimConfig(scene="boulevard")
