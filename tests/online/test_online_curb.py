"""Curb algorithm (Stamos et al., Sec. 6) on an analytic street with a curb."""

from __future__ import annotations

import numpy as np
import pytest

from prc_slam.online import GroundDetector, coarse_classify
from prc_slam.online.curb import detect_curbs
from prc_slam.scan import Scan, SpinningSensor


def street_with_step(
    step: float, curb_y: float = -5.0, height: float = 1.7, cols: int = 360
) -> tuple[Scan, np.ndarray]:
    """Road z = -height for y > curb_y, a step of ``step`` m at y = curb_y, raised ground beyond.
    Returns the scan and the mask of returns on the step's face."""
    sensor = SpinningSensor.create(np.radians(np.arange(0.0, -30.0, -0.25)), cols)
    d = sensor.directions()
    dz = np.minimum(d[..., 2], -1e-6)
    t_road = -height / dz
    y_road = t_road * d[..., 1]
    beyond = y_road < curb_y
    t_face = np.where(d[..., 1] < -1e-6, curb_y / np.minimum(d[..., 1], -1e-6), 1e9)
    z_face = t_face * d[..., 2]
    on_face = beyond & (z_face >= -height) & (z_face <= -height + step)
    t_walk = (-height + step) / dz
    t = np.where(~beyond, t_road, np.where(on_face, t_face, t_walk))
    t = np.where((d[..., 2] < -1e-3) & (t < 60), t, 0.0)
    return Scan(t.astype(np.float32), sensor), on_face & (t > 0)


def run(scan: Scan):
    det = GroundDetector()
    coarse = coarse_classify(scan)
    ground = det.process(scan, coarse)
    return detect_curbs(scan, coarse, ground, det.height), ground


def test_curb_is_found_with_a_polyline():
    scan, face = street_with_step(0.12)
    res, ground = run(scan)
    assert face.sum() > 100
    assert res.mask[face].mean() > 0.5
    assert not (res.mask & ground).any()
    assert (res.mask & ~face).sum() < 0.1 * res.mask.sum()
    assert res.polylines and max(len(p) for p in res.polylines) >= 3
    longest = max(res.polylines, key=len)
    np.testing.assert_allclose(longest[:, 1], -5.0, atol=0.05)  # the polyline runs along the curb


def test_a_one_metre_step_is_not_a_curb():
    scan, face = street_with_step(1.0)
    res, _ = run(scan)
    assert not res.mask[face].any()


def test_no_ground_height_no_curbs():
    scan, _ = street_with_step(0.12)
    coarse = coarse_classify(scan)
    res = detect_curbs(scan, coarse, np.zeros(scan.shape, bool), None)
    assert not res.mask.any() and res.polylines == []


def test_detect_command_writes_labels_json_and_recording(tmp_path):
    import json

    import rerun.chunk as rc
    from typer.testing import CliRunner

    from data_tools import open_dataset
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator
    from prc_slam.cli import app

    root = write_sequence(Simulator(SimConfig(frames=2, seed=6)), tmp_path / "sim")
    res = CliRunner().invoke(
        app,
        [
            "detect",
            str(root),
            "--labels-out",
            str(tmp_path / "labels"),
            "--json",
            str(tmp_path / "d.json"),
            "--rrd",
            str(tmp_path / "d.rrd"),
            "--log-every",
            "1",
        ],
    )
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "d.json").read_text())
    assert m["frames"] == 2 and m["per_class"]["ground"]["precision"] > 0.95
    n1 = open_dataset(root)[1].n_points
    assert m["points_per_s_after_first"] == pytest.approx(n1 / (m["seconds"] - m["seconds_first"]))
    labels = np.fromfile(tmp_path / "labels" / "000000.label", dtype=np.uint32)
    assert len(labels) == open_dataset(root)[0].n_points  # one label per input point
    assert set(np.unique(labels)) <= {2, 5, 65, 66, 68, 69}
    paths = {c.entity_path for c in rc.RrdReader(str(tmp_path / "d.rrd")).store().stream()}
    assert {
        "/range_image/online",
        "/world/detections/curbs",
        "/world/detections/cars",
        "/world/sensor/online",
        "/world/sensor/raw",
    } <= paths
    paper = CliRunner().invoke(app, ["detect", str(root), "--paper", "--json", str(tmp_path / "p.json")])
    assert paper.exit_code == 0, paper.output
    p = json.loads((tmp_path / "p.json").read_text())
    assert p["objects"]["curb"]["present"] == m["objects"]["curb"]["present"]
    assert p["per_class"] != m["per_class"]  # the paper's readings give other labels


def test_vehicle_objects_found_hand_computed():
    from prc_slam.evaluation.metrics import objects_found

    gt = np.array([[65, 65, 65, 2], [65, 65, 0, 0], [65, 0, 0, 0]])
    inst = np.array([[1, 1, 1, 0], [2, 2, 0, 0], [3, 0, 0, 0]])
    lab = np.array([[65, 0, 0, 2], [0, 0, 0, 0], [65, 0, 0, 0]])
    # car 1: 1 of 3 returns (>= 30 %) found; car 2: 0 of 2 missed; car 3: 1 return, too small to count
    assert objects_found(gt, inst, lab, 65, min_points=2, share=0.3) == (1, 2)


def test_profiler_defaults_and_the_car_height_floor():
    from data_tools.sim.simulator import SimConfig, Simulator
    from prc_slam.online.car import CarParams, detect_cars
    from prc_slam.online.coarse import coarse_classify
    from prc_slam.online.detector import OnlineDetector, default_coarse_params
    from prc_slam.scan import Scan

    sim = Simulator(SimConfig(sensor="profiler-urban", frames=4, lines_per_frame=99))
    scans = [Scan(sim.frame(i).ranges, sim.sensor.model) for i in range(4)]
    assert default_coarse_params(scans[0]).min_step == 0.1 and default_coarse_params(scans[0]).centred  # profilers
    spinning = Simulator(SimConfig(frames=1))
    assert default_coarse_params(Scan(spinning.frame(0).ranges, spinning.sensor.model)).min_step == 0.0
    det = OnlineDetector()
    for s in scans:
        det.process(s)
    z_ground = det.ground.height
    assert z_ground is not None
    coarse = coarse_classify(scans[-1], default_coarse_params(scans[-1]))
    z = scans[-1].slot_xyz()[..., 2]
    paper = detect_cars(scans[-1], coarse, z_ground, params=CarParams(min_above_ground=0.0)).mask
    ours = detect_cars(scans[-1], coarse, z_ground).mask
    assert (paper & (z < z_ground + 0.3)).any()  # the paper's cars reach down to the road
    assert not (ours & (z < z_ground + 0.3)).any() and (ours == (paper & (z >= z_ground + 0.3))).all()


def test_possible_curbs_after_every_ground_run_hand_computed():
    from prc_slam.online.curb import possible_curbs

    # one line, outwards: road (G), a curb face (V), the sidewalk (G again), a wall (V)
    y = np.array([2.0, 2.5, 3.0, 3.0, 3.0, 3.5, 4.0, 4.5, 4.5, 4.5])
    z = np.array([-1.7, -1.7, -1.7, -1.69, -1.6, -1.55, -1.55, -1.55, -1.545, 0.5])
    xyz = np.stack([np.zeros_like(y), y, z], axis=1)
    codes = np.array([68, 68, 68, 69, 69, 68, 68, 68, 69, 69], np.uint8)
    ground = np.array([1, 1, 1, 0, 0, 1, 1, 1, 0, 0], bool)
    args = (xyz, codes, ground, np.ones(10, bool), np.arange(10)[None, :], np.array([-1.7]), 2.0, 30, 0.01)
    pcs = possible_curbs(*args, False)[0]
    # TestUnder is false only within 1 cm of the farthest earlier range: the face's and the
    # wall's lowest returns. Read online, "the last ground point" is the latest one: a PC
    # after each run of ground
    assert pcs[pcs >= 0].tolist() == [3, 8]
    offline = possible_curbs(*args, True)[0]
    assert offline[offline >= 0].tolist() == [8]  # only after the line's final ground return
    low = possible_curbs(*args[:6], 0.1, 30, 0.01, False)[0]
    assert low[low >= 0].tolist() == [3]  # the wall starts 0.155 m up: beyond t_high = 0.1


def test_region_growing_joins_only_near_neighbours():
    from prc_slam.prc.kernels import connected_components, connected_components_within

    mask = np.array([[1, 1, 0, 1], [0, 1, 0, 1]], bool)
    xyz = np.zeros((2, 4, 3))
    xyz[0, :, 0] = [0.0, 0.1, 5.0, 9.0]
    xyz[1, :, 0] = [0.0, 2.0, 0.0, 9.1]  # (1, 1) lies 1.9 m from (0, 1) above it
    lab, n = connected_components_within(mask, xyz, 0.5, False)
    assert n == 3 and lab[0, 0] == lab[0, 1] != lab[1, 1] and lab[0, 3] == lab[1, 3]
    lab_inf, n_inf = connected_components_within(mask, xyz, np.inf, False)
    plain, n_plain = connected_components(mask, False)
    assert n_inf == n_plain == 2 and (lab_inf == plain).all()


def test_curb_height_limits():
    from prc_slam.online.curb import CurbParams

    scan, face = street_with_step(0.12)
    det = GroundDetector()
    coarse = coarse_classify(scan)
    ground = det.process(scan, coarse)
    assert detect_curbs(scan, coarse, ground, det.height, CurbParams(min_height=0.05)).mask[face].mean() > 0.5
    # a region lower than min_height is no curb; t_curb below the face's height rejects it too
    assert not detect_curbs(scan, coarse, ground, det.height, CurbParams(min_height=0.15)).mask.any()
    assert not detect_curbs(scan, coarse, ground, det.height, CurbParams(t_curb=0.05)).mask.any()
