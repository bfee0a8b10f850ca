"""The LiDAR simulator: determinism, ground truth, noise statistics, motion distortion, export."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from data_tools import open_dataset
from data_tools.formats.kitti import KittiSequence
from data_tools.sim import simulator as S
from data_tools.sim.dataset import SimSequence, export_kitti, write_sequence
from data_tools.sim.simulator import NoiseConfig, SimConfig, Simulator
from prc_slam import labels as L


@pytest.fixture(scope="module")
def urban_sim() -> Simulator:
    return Simulator(SimConfig(frames=40, noise=NoiseConfig(range_sigma=0.0, mixed_pixel_rate=0.0)))


def world_points(sim: Simulator, frame: S.SimFrame) -> tuple[np.ndarray, np.ndarray]:
    """World coordinates of a spinning frame's returns with per-column poses, and the mask."""
    valid = frame.ranges > 0
    local = sim.sensor.model.to_xyz(frame.ranges)  # (rows, cols, 3) in the sensor frame
    rot, pos = frame.line_poses[:, :3, :3], frame.line_poses[:, :3, 3]
    world = np.einsum("cij,rcj->rci", rot, local) + pos[None]
    return world[valid], valid


def closest_labels(sim: Simulator, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mesh = sim.scene.mesh
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices), o3d.core.Tensor(mesh.triangles.astype(np.uint32)))
    ans = scene.compute_closest_points(o3d.core.Tensor(pts.astype(np.float32)))
    tri = ans["primitive_ids"].numpy().astype(np.int64)
    dist = np.linalg.norm(ans["points"].numpy() - pts, axis=1)
    return mesh.label[tri], dist


def test_same_seed_same_bytes_other_seed_other_scene(tmp_path):
    cfg = SimConfig(frames=2, seed=3, noise=NoiseConfig(outlier_rate=0.01))
    a = write_sequence(Simulator(cfg), tmp_path / "a")
    b = write_sequence(Simulator(cfg), tmp_path / "b")
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files and files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    other = Simulator(cfg.model_copy(update={"seed": 4}))
    assert other.scene.mesh.n_triangles != Simulator(cfg).scene.mesh.n_triangles or not np.array_equal(
        other.scene.mesh.vertices, Simulator(cfg).scene.mesh.vertices
    )


def test_ground_truth_class_agrees_with_the_mesh(urban_sim):
    frame = urban_sim.frame(3)
    pts, valid = world_points(urban_sim, frame)
    kind = frame.noise_kind[valid]
    clean = (kind == S.CLEAN) | (kind == S.GLASS_INSIDE)
    rng = np.random.default_rng(0)
    pick = rng.choice(np.flatnonzero(clean), 3000, replace=False)
    lab, dist = closest_labels(urban_sim, pts[pick])
    assert np.median(dist) < 1e-3  # exact ranges: returns lie on the mesh
    agree = lab == frame.labels[valid][pick]
    assert agree.mean() > 0.99  # the rest: points on an edge shared by two classes (curb/road)


def test_class_mix_is_urban(urban_sim):
    f = urban_sim.frame(10)
    valid = f.ranges > 0
    share = {c: float((f.labels[valid] == c).mean()) for c in (L.GROUND, L.BUILDING, L.VEGETATION, L.VEHICLE)}
    assert 0.3 < share[L.GROUND] < 0.75
    assert share[L.BUILDING] > 0.05 and share[L.VEHICLE] > 0.01 and share[L.VEGETATION] > 0.01


def test_gaussian_range_noise_matches_sigma(urban_sim):
    noisy = Simulator(
        urban_sim.config.model_copy(update={"noise": NoiseConfig(range_sigma=0.05, mixed_pixel_rate=0.0)})
    )
    a, b = urban_sim.frame(2), noisy.frame(2)
    both = (a.noise_kind == S.CLEAN) & (b.noise_kind == S.CLEAN)
    diff = (b.ranges - a.ranges)[both]
    assert abs(diff.std() - 0.05) < 0.003 and abs(diff.mean()) < 0.002


def test_outlier_rate_is_statistically_right(urban_sim):
    rate = 0.05
    sim = Simulator(urban_sim.config.model_copy(update={"noise": NoiseConfig(outlier_rate=rate)}))
    f = sim.frame(1)
    n = f.ranges.size
    measured = (f.noise_kind == S.OUTLIER).mean()
    assert abs(measured - rate) < 4 * np.sqrt(rate * (1 - rate) / n)
    out = f.noise_kind == S.OUTLIER
    assert (f.labels[out] == L.NOISE).all() and (f.ranges[out] > 0).all()
    assert f.ranges[out].max() <= sim.sensor.max_range


def test_glass_and_mixed_pixel_switches(urban_sim):
    cfg = urban_sim.config
    never = Simulator(cfg.model_copy(update={"noise": NoiseConfig(glass_inside=0.0)})).frame(4)
    always = Simulator(cfg.model_copy(update={"noise": NoiseConfig(glass_inside=1.0)})).frame(4)
    assert (never.noise_kind == S.DROP_GLASS).sum() > 100 and not (never.noise_kind == S.GLASS_INSIDE).any()
    assert (always.noise_kind == S.GLASS_INSIDE).sum() > 100 and not (always.noise_kind == S.DROP_GLASS).any()
    half = Simulator(cfg.model_copy(update={"noise": NoiseConfig(glass_inside=0.5)})).frame(4)
    dropped = (half.noise_kind == S.DROP_GLASS).sum() / (never.noise_kind == S.DROP_GLASS).sum()
    assert 0.35 < dropped < 0.75  # first panes drop half; rays through one pane may meet another
    mixed = Simulator(cfg.model_copy(update={"noise": NoiseConfig(mixed_pixel_rate=1.0, range_sigma=0.0)})).frame(4)
    m = mixed.noise_kind == S.MIXED
    assert m.sum() > 100 and (mixed.labels[m] == L.NOISE).all()
    clean = urban_sim.frame(4)
    # a mixed range lies between the foreground and the background it replaced
    assert (mixed.ranges[m] <= clean.ranges[m] + 1e-4).all()


def test_grazing_dropouts_grow_with_incidence(urban_sim):
    f = urban_sim.frame(5)
    far_ground_rows = slice(40, 64)
    assert (f.noise_kind == S.DROP_GRAZING).sum() > 0
    # the lowest beams hit the road at steep angles: few grazing dropouts there
    near = (f.noise_kind[-8:] == S.DROP_GRAZING).mean()
    assert near < (f.noise_kind[far_ground_rows] == S.DROP_GRAZING).mean() + 0.05


def test_motion_distortion_is_real():
    sim = Simulator(SimConfig(frames=80, speed=10.0, stops=0, noise=NoiseConfig(range_sigma=0.0, mixed_pixel_rate=0.0)))
    f = sim.frame(5)  # cruising at 10 m/s (the only stop comes later)
    valid = f.ranges > 0
    local = sim.sensor.model.to_xyz(f.ranges)[valid]
    per_col, _ = world_points(sim, f)
    single = local @ f.pose[:3, :3].T + f.pose[:3, 3]
    shift = np.linalg.norm(per_col - single, axis=1)
    # columns fired 0.05 s before/after the reference time move by up to speed * 0.05 s
    assert 0.4 < shift.max() < 10.0 * 0.06
    _, d_true = closest_labels(sim, per_col[::20])
    _, d_single = closest_labels(sim, single[::20])
    assert np.median(d_true) < 1e-3 < np.median(d_single)


def test_dataset_reader_and_kitti_export_round_trip(tmp_path):
    sim = Simulator(SimConfig(frames=3, seed=1, noise=NoiseConfig(outlier_rate=0.01)))
    root = write_sequence(sim, tmp_path / "sim")
    seq = open_dataset(root)
    assert isinstance(seq, SimSequence) and len(seq) == 3
    scan = seq[1]
    assert scan.gt_labels is not None and scan.slot_times().shape == scan.shape
    kitti = export_kitti(seq, tmp_path / "kitti")
    k = open_dataset(kitti)
    assert isinstance(k, KittiSequence)
    np.testing.assert_allclose(k.poses, seq.poses, atol=1e-8)
    for i in range(3):
        a, b = seq[i], k[i]
        assert b.n_points == a.n_points
        np.testing.assert_array_equal(b.reference_labels(), a.gt_labels[a.valid])
        np.testing.assert_allclose(b.points(), a.slot_xyz()[a.valid], atol=1e-5)
        assert b.meta["collisions"] == 0  # the reader recovers the simulator's 2048 columns


def test_profiler_backpack_dead_angle_and_continuous_rows():
    sim = Simulator(SimConfig(scene="forest", sensor="profiler-backpack", frames=2, lines_per_frame=20))
    f = sim.frame(0)
    assert sim.sensor.model.continuous_rows
    assert (f.ranges[sim.blocked] == 0).all() and (f.noise_kind[sim.blocked] == S.DEAD_ANGLE).all()
    dead = np.degrees(sim.sensor.dead_angle[1] - sim.sensor.dead_angle[0])
    assert dead == pytest.approx(55.0)
    assert np.all(np.diff(f.slot_times.ravel()) > 0)  # every slot at its own time


def test_wind_moves_foliage_only():
    sim = Simulator(SimConfig(scene="forest", sensor="vlp16", frames=2, wind=0.3))
    a, b = sim._moving_scene(0.0), sim._moving_scene(1.1)
    mesh = sim.scene.mesh
    leaves = np.flatnonzero(sim.foliage)[:2000]
    centres = mesh.vertices[mesh.triangles[leaves]].mean(axis=1)
    origin = centres + np.array([0.0, 0.0, 5.0])
    rays = o3d.core.Tensor(np.column_stack([origin, np.tile([0, 0, -1.0], (len(origin), 1))]).astype(np.float32))
    ta, tb = a.cast_rays(rays)["t_hit"].numpy(), b.cast_rays(rays)["t_hit"].numpy()
    both = np.isfinite(ta) & np.isfinite(tb)
    assert np.mean(np.abs(ta[both] - tb[both]) > 1e-3) > 0.3
    calm = Simulator(SimConfig(scene="forest", sensor="vlp16", frames=2, wind=0.0))
    assert calm._moving_scene(0.0) is None and not len(calm._moving_idx)
