"""The organiser (data_tools.organize): any sweep of points -> a range image with an exact slot map.

Hand-made sweeps with known rings and firings, hypothesis properties (one slot per point,
labels back in input order, the same organisation for every order of one sweep), KITTI-layout
bins written from the shared Ouster sweeps (ring-major both ways, column-major) scored against
the sensor's own (beam, measurement) grid, the real multi-sensor sweeps, and bad input.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from data_tools.errors import DataError
from data_tools.organize import Organizer, estimate_beam_offset
from prc_slam import labels as L
from tests.conftest import SHARED_DATA

DATA = SHARED_DATA
OUSTER = sorted((DATA / "ouster" / "decoded").glob("*.npz"))
MULTI = DATA / "multisensor"


def spinning_sweep(rings=8, cols=360, keep=0.8, seed=0, direction=1, el0=-15.0, del_=2.0, az0=0.0):
    """A spinning sensor's sweep: ``rings`` beams ``del_`` degrees apart, ``cols`` firings per
    turn, each return kept with probability ``keep``. Returns xyz (ring-major, azimuth turning
    in ``direction``) and every point's beam and firing."""
    rng = np.random.default_rng(seed)
    beam, firing = np.meshgrid(np.arange(rings), np.arange(cols), indexing="ij")
    beam, firing = beam.ravel(), firing.ravel()
    kept = rng.random(beam.size) < keep
    beam, firing = beam[kept], firing[kept]
    az = np.radians(az0) + direction * (firing + 0.5) * 2 * np.pi / cols
    el = np.radians(el0 + del_ * (rings - 1 - beam))  # beam 0 is the top beam
    r = rng.uniform(3.0, 40.0, beam.size)
    xyz = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=1)
    return xyz.astype(np.float32), beam, firing


def column_major(beam, firing):
    """The order that lists all beams of one firing, then the next firing."""
    return np.lexsort((beam, firing))


def slot_agreement(scan, beam, col) -> float:
    """Share of points in their true slot, up to the organiser's own row numbering, a column
    shift per beam and the column direction (both are the organiser's free choices)."""
    cols = scan.shape[1]
    row, c = np.divmod(scan.point_slot, cols)
    best = 0.0
    for sign in (1, -1):
        key = (c - sign * col) % cols
        good = np.zeros(len(beam), bool)
        used: set[int] = set()
        for b in np.unique(beam):
            sel = beam == b
            pairs = row[sel] * cols + key[sel]
            u, n = np.unique(pairs, return_counts=True)
            k = int(u[np.argmax(n)])
            if k // cols in used:  # two beams in one row: the smaller one counts as wrong
                continue
            used.add(k // cols)
            good[sel] = pairs == k
        best = max(best, float(good.mean()))
    return best


# ----------------------------------------------------------------------------- hand-made sweeps


def test_small_sweep_by_hand():
    """2 beams x 16 firings, ring-major: every point in the slot of its beam and firing."""
    xyz, beam, firing = spinning_sweep(rings=2, cols=16, keep=1.0, del_=10.0)
    scan = Organizer(cols=16).scan(xyz)
    assert scan.shape == (2, 16)
    assert scan.meta["organize"]["method"] == "ring-major"
    row, col = np.divmod(scan.point_slot, 16)
    np.testing.assert_array_equal(row, beam)  # top beam first
    np.testing.assert_array_equal(col, firing)  # column 0 is the first firing
    np.testing.assert_allclose(scan.ranges.ravel()[scan.point_slot], np.linalg.norm(xyz, axis=1), rtol=1e-6)
    np.testing.assert_allclose(np.degrees(scan.sensor.altitude), [-5.0, -15.0], atol=1e-4)
    # the sensor model puts every slot where its point is
    rays = scan.sensor.to_xyz(scan.ranges).reshape(-1, 3)[scan.point_slot]
    np.testing.assert_allclose(rays, xyz, atol=1e-3 * np.linalg.norm(xyz, axis=1).max())


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("layout", ["ring-major", "ring-major-reversed", "column-major", "shuffled"])
def test_layouts_give_the_true_slots(layout, direction):
    xyz, beam, firing = spinning_sweep(rings=16, cols=720, keep=0.7, direction=direction, seed=3)
    order = {
        "ring-major": np.arange(len(xyz)),
        "ring-major-reversed": np.arange(len(xyz))[::-1],
        "column-major": column_major(beam, firing),
        "shuffled": np.random.default_rng(1).permutation(len(xyz)),
    }[layout]
    scan = Organizer().scan(xyz[order])
    rep = scan.meta["organize"]
    expected_method = {"shuffled": "beams", "column-major": "column-major"}.get(layout, "ring-major")
    assert rep["method"] == expected_method
    assert (rep["rings"], rep["cols"], rep["collisions_pct"], rep["warnings"]) == (16, 720, 0.0, [])
    assert slot_agreement(scan, beam[order], firing[order]) == 1.0


def test_ring_field_any_numbering():
    """Interleaved channel ids (VLP-16 style) go to rows by elevation, top beam first."""
    xyz, beam, firing = spinning_sweep(rings=16, cols=900, keep=0.9, seed=2)
    ids = np.array([0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5, 13, 6, 14, 7, 15])[beam] + 100
    order = column_major(beam, firing)
    scan = Organizer().scan(xyz[order], ring=ids[order])
    assert scan.meta["organize"]["method"] == "ring-field"
    np.testing.assert_array_equal(scan.point_slot // scan.shape[1], beam[order])


def test_beam_table_kept_across_frames():
    """A later sweep missing a beam keeps every other beam in its row (the table is per sequence)."""
    org = Organizer()
    xyz, *_ = spinning_sweep(rings=8, cols=360, seed=0)
    first = org.scan(xyz[np.argsort(np.random.default_rng(0).random(len(xyz)))])
    xyz2, beam2, _ = spinning_sweep(rings=8, cols=360, seed=1)
    keep = beam2 != 3
    second = org.scan(xyz2[keep])
    assert first.shape == second.shape == (8, 360)
    np.testing.assert_array_equal(second.point_slot // 360, beam2[keep])
    rep = second.meta["organize"]
    assert rep["rings"] == 7 and rep["empty_rows"] == 1


def bent_sweep(seed, bend, only_bent=(), missing=()):
    """A ring-major 16-beam sweep (2 deg apart) whose returns in the second half turn rise by
    ``bend`` degrees (a motion-compensated sweep bends its rings so), beams ``only_bent``
    keeping only a fifth of the first half's returns and beams ``missing`` none."""
    xyz, beam, firing = spinning_sweep(rings=16, cols=720, keep=0.9, seed=seed)
    az = np.arctan2(xyz[:, 1], xyz[:, 0])
    second = az < 0.0  # firings 360..719
    keep = ~np.isin(beam, missing) & ~(np.isin(beam, only_bent) & ~second & (firing >= 72))
    r = np.linalg.norm(xyz, axis=1)
    el = np.arcsin(xyz[:, 2] / r) + np.where(second, np.radians(bend), 0.0)
    bent = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=1)
    return bent[keep].astype(np.float32), beam[keep], firing[keep]


def test_rings_keep_their_rows_when_their_elevation_bends():
    """KITTI 00 frames 7-15: rings bent along the azimuth by up to a beam gap have medians nearer
    a neighbour's beam; each still gets its own row, by the first sweep's ring order (a missing
    ring skipped). The nearest beam by median alone doubled rows 3 and 9 here."""
    org = Organizer()
    org.scan(bent_sweep(0, 0.0)[0])
    xyz, beam, _ = bent_sweep(1, 1.3, only_bent=(3, 9), missing=(12,))
    scan = org.scan(xyz)
    rep = scan.meta["organize"]
    assert (rep["rings"], rep["empty_rows"], rep["collisions_pct"], rep["warnings"]) == (15, 1, 0.0, [])
    np.testing.assert_array_equal(scan.point_slot // scan.shape[1], beam)


def test_a_ring_with_returns_over_less_than_half_a_turn_is_its_own_ring():
    """An upper ring that only sees a building over 100 deg, then the next ring from the cut
    azimuth on: a ring of its own (it was merged with the next one when a ring had to travel
    half a turn before the azimuth could restart)."""
    org = Organizer()
    org.scan(spinning_sweep(rings=16, cols=720, keep=0.9, seed=0)[0])
    xyz, beam, firing = spinning_sweep(rings=16, cols=720, keep=0.9, seed=1)
    keep = ~((beam == 3) & ((firing < 400) | (firing > 600))) & ~((beam == 7) & (firing > 100))
    scan = org.scan(xyz[keep])
    rep = scan.meta["organize"]
    assert (rep["rings"], rep["empty_rows"], rep["collisions_pct"]) == (16, 0, 0.0)
    np.testing.assert_array_equal(scan.point_slot // scan.shape[1], beam[keep])


def test_rings_out_of_the_first_sweeps_order_are_reported():
    """A later sweep whose rings come in another order than the first's: a warning, and the rows
    from the nearest beam elevations."""
    org = Organizer()
    org.scan(spinning_sweep(rings=16, cols=720, keep=0.9, seed=0)[0])
    xyz, beam, _ = spinning_sweep(rings=16, cols=720, keep=0.9, seed=1)
    order = np.lexsort((np.arange(len(beam)), -beam))  # bottom ring first, each ring in firing order
    scan = org.scan(xyz[order])
    assert any("ring order" in w for w in scan.meta["organize"]["warnings"])
    np.testing.assert_array_equal(scan.point_slot // scan.shape[1], beam[order])


def test_no_return_points_keep_their_entry():
    xyz, *_ = spinning_sweep(rings=4, cols=180, seed=4)
    xyz = xyz.copy()
    xyz[[3, 50]] = np.nan
    xyz[77] = 0.0
    scan = Organizer().scan(xyz)
    assert scan.meta["organize"]["nonfinite_points"] == 3
    assert scan.n_points == len(xyz) and np.isfinite(scan.points()).all()
    assert (scan.points()[[3, 50, 77]] == 0).all()
    labels = np.where(scan.valid, L.BUILDING, L.NO_RETURN).astype(np.uint8)
    per_point = scan.per_point(labels)
    assert (per_point[[3, 50, 77]] == L.NO_RETURN).all()
    assert (np.delete(per_point, [3, 50, 77]) == L.BUILDING).all()


def test_per_point_times_and_attributes():
    xyz, beam, firing = spinning_sweep(rings=4, cols=360, seed=5)
    times = 100.0 + firing * (0.1 / 360)
    gt = np.where(beam > 1, L.GROUND, L.BUILDING).astype(np.uint8)
    scan = Organizer().scan(xyz, times=times, intensity=beam.astype(np.float32), gt_point_labels=gt, frame_time=100.0)
    np.testing.assert_allclose(scan.point_times(), times)
    np.testing.assert_array_equal(scan.per_point(scan.intensity), beam)
    np.testing.assert_array_equal(scan.reference_labels(), gt)
    np.testing.assert_array_equal(scan.per_point(scan.gt_labels), gt)
    assert scan.meta["frame_time"] == 100.0


def test_organized_grid():
    """An (H, W, 3) cloud given bottom beam first: rows reordered top first, NaN = no return."""
    xyz, beam, firing = spinning_sweep(rings=6, cols=64, keep=1.0, seed=6)
    grid = np.zeros((6, 64, 3), np.float32)
    grid[beam, firing] = xyz
    grid = grid[::-1].copy()
    grid[2, 5] = np.nan
    scan = Organizer().scan_organized(grid, times=np.linspace(0, 0.1, 64))
    assert scan.shape == (6, 64) and scan.meta["organize"]["nonfinite_points"] == 1
    assert scan.n_points == 6 * 64
    row, col = np.divmod(scan.point_slot, 64)
    np.testing.assert_array_equal(row, np.repeat(np.arange(6)[::-1], 64))
    np.testing.assert_array_equal(col, np.tile(np.arange(64), 6))
    assert np.all(np.diff(scan.sensor.altitude) < 0)
    assert scan.per_point(np.ones(scan.shape, np.uint8) * scan.valid)[2 * 64 + 5] == 0


# ----------------------------------------------------------------------------- properties


@st.composite
def sweeps(draw):
    rings = draw(st.integers(2, 24))
    cols = draw(st.sampled_from([120, 360, 512, 1000]))
    keep = draw(st.floats(0.55, 1.0))
    direction = draw(st.sampled_from([1, -1]))
    del_ = draw(st.floats(0.8, 3.0))
    az0 = draw(st.floats(-180, 180))
    seed = draw(st.integers(0, 10_000))
    return spinning_sweep(rings, cols, keep, seed, direction, -10.0, del_, az0), cols


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sweeps(), st.sampled_from(["reversed", "column-major", "shuffled"]))
def test_every_order_gives_the_same_organisation(sweep, reorder):
    (xyz, beam, firing), cols = sweep
    perm = {
        "reversed": np.arange(len(xyz))[::-1],
        "column-major": column_major(beam, firing),
        "shuffled": np.random.default_rng(0).permutation(len(xyz)),
    }[reorder]
    a = Organizer(cols=cols).scan(xyz)
    b = Organizer(cols=cols).scan(xyz[perm])
    # every input point has exactly one slot inside the image
    for s, n in ((a, len(xyz)), (b, len(xyz))):
        assert s.point_slot.shape == (n,) and s.point_slot.min() >= 0 and s.point_slot.max() < s.ranges.size
    # labels computed per slot come back in input order: tag every slot with its own index
    tags = np.arange(b.ranges.size).reshape(b.shape)
    np.testing.assert_array_equal(b.per_point(tags), b.point_slot)
    # the same rows, and columns equal up to a shift and the direction
    row_a, col_a = np.divmod(a.point_slot[perm], cols)
    row_b, col_b = np.divmod(b.point_slot, cols)
    np.testing.assert_array_equal(row_a, row_b)
    assert any(len(np.unique((col_b - sign * col_a) % cols)) == 1 for sign in (1, -1))


# ----------------------------------------------------------------------------- bad input, warnings


def test_unorganisable_sweep_is_an_error():
    """Points without beams, ring field or order (uniform directions, random order)."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(20000, 3))
    xyz = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(2, 30, (20000, 1))
    with pytest.raises(DataError, match=r"cloud\.bin: cannot organise"):
        Organizer().scan(xyz, source="cloud.bin")


def test_collapse_is_never_silent(caplog):
    """Too few columns for the sweep: the shared slots are warned about and counted."""
    xyz, *_ = spinning_sweep(rings=16, cols=720, seed=7)
    with caplog.at_level(logging.WARNING, logger="prc_slam.organize"):
        scan = Organizer(cols=500).scan(xyz, source="s.bin")
    rep = scan.meta["organize"]
    assert rep["collisions_pct"] > 12 and len(rep["warnings"]) == 1
    assert "s.bin" in caplog.text and "share a range-image slot" in caplog.text
    with pytest.raises(DataError, match=r"s\.bin: cannot organise: .*share a range-image slot"):
        Organizer(cols=60).scan(xyz, source="s.bin")


def test_expected_beams_checked(caplog):
    xyz, *_ = spinning_sweep(rings=16, cols=720, seed=8)
    with caplog.at_level(logging.WARNING, logger="prc_slam.organize"):
        scan = Organizer(rows=64).scan(xyz, source="x.bin")
    assert any("16 rings found, the sensor has 64" in w for w in scan.meta["organize"]["warnings"])
    assert "16 rings found" in caplog.text


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"xyz": np.zeros((5, 2))}, "points must be an \\(N, 3\\) array"),
        ({"xyz": np.full((5, 3), np.nan)}, "no point with a return"),
        ({"xyz": np.ones((5, 3)), "ring": np.zeros(4)}, "ring has shape"),
        ({"xyz": np.ones((5, 3)), "ring": np.full(5, 0.5)}, "the ring field holds non-integer"),
    ],
)
def test_bad_input(kwargs, message):
    with pytest.raises(DataError, match=r"f\.pcd: " + message):
        Organizer().scan(source="f.pcd", **kwargs)


def test_order_method_refuses_an_unordered_sweep():
    xyz, *_ = spinning_sweep(rings=8, cols=360, seed=9)
    xyz = xyz[np.random.default_rng(0).permutation(len(xyz))]
    with pytest.raises(DataError, match="point order is not consistent"):
        Organizer(method="order").scan(xyz, source="o.bin")


def test_beam_offset_estimated():
    """Beams leaving the axis 25 mm out (Ouster-like): the offset is found from the points."""
    xyz, *_ = spinning_sweep(rings=32, cols=512, seed=10, del_=0.7)
    rho = np.hypot(xyz[:, 0], xyz[:, 1])
    xyz = xyz.copy()
    xyz[:, :2] *= ((rho + 0.025) / rho)[:, None]  # the beam starts 25 mm out along its azimuth
    assert estimate_beam_offset(xyz) == pytest.approx(0.025, abs=0.0015)


# ----------------------------------------------------------------------------- real sweeps

needs_ouster = pytest.mark.skipif(not OUSTER, reason="../shared/data/ouster/decoded not present")


def ouster_layout(path: Path, layout: str):
    z = np.load(path)
    valid = z["range_mm"] > 0
    H, W = valid.shape
    b, m = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    if layout.startswith("column-major"):
        b, m = b.T, m.T
    if layout.endswith("reversed"):
        b, m = b[:, ::-1], m[:, ::-1]  # azimuth running the other way round
    b, m = b.ravel(), m.ravel()
    keep = valid[b, m]
    return z["xyz_lidar_m"][b[keep], m[keep]], b[keep], m[keep]


@needs_ouster
@pytest.mark.parametrize("layout", ["ring-major", "ring-major-reversed", "column-major", "column-major-reversed"])
@pytest.mark.parametrize("path", [p for p in OUSTER if "frame1" not in p.name and "frame2" not in p.name], ids=str)
def test_ouster_sweeps_in_kitti_layout(path, layout, tmp_path):
    """Acceptance: KITTI-layout bins from real Ouster sweeps, >= 98 % of points in their true slot."""
    xyz, beam, meas = ouster_layout(path, layout)
    pts = np.concatenate([xyz, np.zeros((len(xyz), 1), np.float32)], axis=1).astype(np.float32)
    (tmp_path / "velodyne").mkdir()
    pts.tofile(tmp_path / "velodyne" / "000000.bin")
    from data_tools.formats.kitti import KittiSequence

    scan = KittiSequence(tmp_path)[0]
    rep = scan.meta["organize"]
    assert rep["method"] == ("column-major" if layout.startswith("column") else "ring-major")
    assert rep["rings"] == 128 and rep["cols"] == 1024
    assert slot_agreement(scan, beam, meas) >= 0.98
    assert rep["collisions_pct"] < 2.0 and rep["warnings"] == []


def read_pcd(path: Path) -> np.ndarray:
    """A binary PCD as a structured array (the few types the shared sweeps use)."""
    raw = path.read_bytes()
    head, _, body = raw.partition(b"DATA binary\n")
    h = {ln.split()[0]: ln.split()[1:] for ln in head.decode().splitlines() if ln and not ln.startswith("#")}
    types = {("F", "4"): "<f4", ("U", "1"): "u1", ("U", "2"): "<u2", ("U", "4"): "<u4"}
    dt = np.dtype([(n, types[(t, s)]) for n, t, s in zip(h["FIELDS"], h["TYPE"], h["SIZE"], strict=True)])
    return np.frombuffer(body, dt, count=int(h["POINTS"][0]))


#: sensor: (channels, least plausible share of the channels found in one sweep)
SENSORS = {
    "hesai_pandar40p": 40,
    "hesai_pandarqt64": 64,
    "hesai_pandarxt32": 32,
    "hesai_at128": 128,
    "velodyne_vlp16": 16,
}


@pytest.mark.skipif(not MULTI.is_dir(), reason="../shared/data/multisensor not present")
@pytest.mark.parametrize("sensor", sorted(SENSORS))
def test_real_sweeps_organise_plausibly(sensor):
    """Real sweeps of five sensors (points in driver order, xyz only): beams found within the
    sensor's channel count, few slots shared between firings, never more rows than channels."""
    a = read_pcd(MULTI / f"{sensor}.pcd")
    xyz = np.stack([a["x"], a["y"], a["z"]], axis=1)
    scan = Organizer().scan(xyz, source=sensor)
    rep = scan.meta["organize"]
    channels = SENSORS[sensor]
    assert 0.5 * channels <= rep["rings"] <= channels
    shared = rep["collisions_pct"] - 100 * rep["multi_returns"] / len(xyz)
    assert shared < 15.0
    assert scan.n_points == len(xyz)
    if "channel" in a.dtype.names:  # the VLP-16's channel field: rows must agree with it
        with_field = Organizer().scan(xyz, ring=a["channel"], source=sensor)
        assert with_field.meta["organize"]["rings"] == len(np.unique(a["channel"]))
        rows_xyz = scan.point_slot // scan.shape[1]
        rows_field = with_field.point_slot // with_field.shape[1]
        # the same partition into beams (row numbers may differ where a beam is empty)
        mapping = {}
        for r_f, r_x in zip(rows_field, rows_xyz, strict=True):
            mapping.setdefault(r_f, {}).setdefault(r_x, 0)
            mapping[r_f][r_x] += 1
        agree = sum(max(v.values()) for v in mapping.values()) / len(xyz)
        assert agree >= 0.98


def test_summary_for_the_metrics_json():
    from data_tools.organize import OrganizeSummary

    summary = OrganizeSummary()
    org = Organizer(cols=500)
    for seed in (0, 1):
        xyz, *_ = spinning_sweep(rings=16, cols=720, seed=seed)
        summary.add(org.scan(xyz, source=f"{seed}.bin").meta["organize"])
    summary.add(None)
    d = summary.as_dict()
    assert (d["frames"], d["frames_without_report"], d["methods"]) == (2, 1, ["ring-major"])
    assert d["rings"] == {"min": 16, "median": 16.0, "max": 16} and d["cols"] == 500
    assert d["warnings"] == 2 and "0.bin" in d["warning_messages"][0]
    assert d["collisions_pct"]["max"] > 12


@pytest.mark.parametrize("az0", [0.0, 0.25, 0.5, -0.5])
def test_rows_line_up_whatever_the_bin_phase(az0):
    """Returns on the bin centres, the bin edges or between: every row's columns line up with
    the other rows' (one shift for the whole sweep), in every order."""
    xyz, beam, firing = spinning_sweep(rings=32, cols=1024, keep=0.8, seed=11, az0=az0 * 360 / 1024)
    for order in (np.arange(len(xyz)), column_major(beam, firing), np.random.default_rng(2).permutation(len(xyz))):
        scan = Organizer().scan(xyz[order])
        col = scan.point_slot % scan.shape[1]
        shifts = np.unique((col - firing[order]) % 1024)  # columns follow the order's firing direction
        assert len(shifts) == 1, shifts


def test_a_sweep_that_does_not_fit_the_beam_table_is_reported(caplog):
    """Beams found on the first sweep; a later sweep from a sensor with other beam angles."""
    org = Organizer()
    xyz, *_ = spinning_sweep(rings=16, cols=720, seed=12, del_=2.0)
    org.scan(xyz[np.random.default_rng(0).permutation(len(xyz))])
    other, *_ = spinning_sweep(rings=16, cols=720, seed=13, del_=2.0, el0=-14.0)  # half a beam gap off
    with caplog.at_level(logging.WARNING, logger="prc_slam.organize"):
        scan = org.scan(other[np.random.default_rng(1).permutation(len(other))], source="later.bin")
    assert any("beam table does not fit" in w for w in scan.meta["organize"]["warnings"])
    assert "later.bin" in caplog.text


def test_a_ring_field_of_one_value_is_ignored_with_a_warning():
    """Drivers that leave the ring field at 0: the sweep is organised from its order instead."""
    xyz, beam, firing = spinning_sweep(rings=16, cols=720, seed=14)
    scan = Organizer().scan(xyz, ring=np.zeros(len(xyz), np.uint16), source="zero.pcd")
    rep = scan.meta["organize"]
    assert rep["method"] == "ring-major" and rep["rings"] == 16
    assert any("ring field holds one value" in w for w in rep["warnings"])
    assert slot_agreement(scan, beam, firing) == 1.0


@settings(max_examples=80, deadline=None)
@given(
    st.lists(st.floats(-2.0, 2.0), min_size=0, max_size=130),
    st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=300),
)
def test_nearest_beam_counts_the_bounds_at_or_above(bounds, te):
    """The table-guided search gives every point the number of beam bounds at or above its
    elevation (its row), also for repeated bounds, points on a bound and far outside."""
    from data_tools.organize.beams import nearest_beam

    b = np.sort(np.array(bounds, float))[::-1]
    t = np.concatenate([np.array(te), b, [1e6, -1e6]])
    ok = np.ones(len(t), bool)
    ok[::7] = False
    row = nearest_beam(t, ok, b, np.empty(len(t), np.int64))
    expected = np.where(ok, (b[None, :] >= t[:, None]).sum(axis=1), -1)
    np.testing.assert_array_equal(row, expected)


def test_ring_ids_renumbered_between_sweeps_are_caught():
    """A driver that numbers the rings by laser id in one sweep and by elevation in the next: the
    ids are the same set, so the first sweep's table would scramble the rows without a word."""
    xyz, beam, _ = spinning_sweep(rings=16, cols=720, seed=9)
    laser_id = np.array([0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5, 13, 6, 14, 7, 15])  # VLP-16-like interleaving
    org = Organizer()
    first = org.scan(xyz, ring=laser_id[beam], source="0.pcd")
    assert first.meta["organize"]["warnings"] == []
    second = org.scan(xyz, ring=beam, source="1.pcd")  # now numbered top beam first
    assert any("1.pcd: the ring ids are no longer at the elevations" in w for w in second.meta["organize"]["warnings"])
    row = second.point_slot // second.shape[1]
    np.testing.assert_array_equal(row, beam)  # rows by elevation, as the first sweep's
    third = org.scan(xyz, ring=beam, source="2.pcd")
    assert third.meta["organize"]["warnings"] == []  # the rebuilt table holds


def test_rows_other_than_the_sensors_beams_are_warned():
    xyz, *_ = spinning_sweep(rings=16, cols=720, seed=8)
    scan = Organizer(rows=18).scan(xyz, source="x.bin")  # two beams short of --rows, not a quarter
    assert any("16 beams found, the sensor has 18" in w for w in scan.meta["organize"]["warnings"])


def test_a_range_image_almost_empty_is_warned():
    """A column count far above the sweep's firings (a wrong --cols, or one estimated from a ring
    field that is no ring, as Livox's 'line'): no slot is shared, but almost every slot is empty."""
    xyz, *_ = spinning_sweep(rings=16, cols=720, seed=10)
    rep = Organizer(cols=100_000).scan(xyz, source="x.pcd").meta["organize"]
    assert rep["collisions_pct"] == 0.0
    assert any("x.pcd: only 0.6% of the 16 x 100000 range image's slots hold a point" in w for w in rep["warnings"])
    assert Organizer(cols=720).scan(xyz, source="x.pcd").meta["organize"]["warnings"] == []


def test_points_beyond_100_km_are_no_returns():
    """A placeholder coordinate (3e38) is no measurement: without the bound it made a ring of its own."""
    xyz, beam, _ = spinning_sweep(rings=16, cols=720, seed=11)
    far = np.array([[1.0, 2.0, 3e38], [3e38, 0.0, 0.0], [0.0, -3e38, 1.0]] * 40, np.float32)
    scan = Organizer().scan(np.vstack([xyz, far]), source="far.pcd")
    rep = scan.meta["organize"]
    assert rep["rings"] == 16 and rep["cols"] == 720
    assert any("far.pcd: 120 of" in w and "beyond 100 km" in w for w in rep["warnings"])
    row = scan.point_slot[: len(xyz)] // scan.shape[1]
    np.testing.assert_array_equal(row, beam)
    assert len(scan.point_slot) == len(xyz) + len(far)  # every point keeps a slot
    assert (scan.ranges.ravel()[scan.point_slot[len(xyz) :]] == 0).all()  # an empty one


# ----------------------------------------------------------------------------- points in a tilted frame


def tilt(xyz: np.ndarray, deg: float, towards: float) -> tuple[np.ndarray, np.ndarray]:
    """``xyz`` turned by ``deg`` about the horizontal axis at azimuth ``towards`` (deg); the
    rotation (points' frame <- spin frame)."""
    from scipy.spatial.transform import Rotation

    axis = np.array([np.cos(np.radians(towards)), np.sin(np.radians(towards)), 0.0])
    R = Rotation.from_rotvec(np.radians(deg) * axis).as_matrix()
    return (xyz.astype(np.float64) @ R.T).astype(np.float32), R


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(deg=st.floats(1.5, 18.0), towards=st.floats(0.0, 360.0), layout=st.sampled_from(["ring-major", "shuffled"]))
def test_points_in_a_tilted_frame_are_organised_about_the_spin_axis(deg, towards, layout):
    """A sweep given in a frame tilted from the sensor's spin axis (a vehicle frame): the axis is
    found to 0.1 deg, every point lands in the slot it has in the level sweep, the tilt is said,
    and the sensor model's rays point at the points in their own frame."""
    from data_tools.organize import estimate_spin_axis

    xyz, beam, firing = spinning_sweep(rings=16, cols=720, keep=0.8, seed=5, del_=1.0)
    order = np.arange(len(xyz)) if layout == "ring-major" else np.random.default_rng(2).permutation(len(xyz))
    xyz, beam, firing = xyz[order], beam[order], firing[order]
    tilted, R = tilt(xyz, deg, towards)
    axis, found, gain = estimate_spin_axis(tilted)
    assert np.degrees(np.arccos(min(1.0, abs(float(axis @ R[:, 2]))))) < 0.1
    assert found == pytest.approx(deg, abs=0.1) and gain > 1.04
    level, turned = Organizer().scan(xyz), Organizer().scan(tilted)
    assert level.meta["organize"]["warnings"] == []
    assert any("from the points' z axis" in w for w in turned.meta["organize"]["warnings"])
    assert turned.meta["organize"]["collisions_pct"] == 0.0
    assert slot_agreement(turned, beam, firing) == 1.0
    # the same rows (top beam first) and the same columns up to where column 0 starts
    row_l, col_l = np.divmod(level.point_slot, 720)
    row_t, col_t = np.divmod(turned.point_slot, 720)
    np.testing.assert_array_equal(row_t, row_l)
    assert len(np.unique((col_t - col_l) % 720)) == 1
    np.testing.assert_array_equal(turned.points(), tilted)  # the points are not moved
    rays = turned.sensor.to_xyz(turned.ranges).reshape(-1, 3)[turned.point_slot]
    np.testing.assert_allclose(rays, tilted, atol=0.01 * np.linalg.norm(xyz, axis=1).max())
    from prc_slam.scan import sensor_from_description  # the mount survives a description

    again = sensor_from_description(turned.sensor.describe())
    np.testing.assert_allclose(again.directions(), turned.sensor.directions(), atol=1e-6)  # (9 decimals)


def test_a_level_sweep_is_left_about_z():
    """Below a 1 deg tilt (KITTI's own sweeps: 0.36 deg) nothing changes: the organisation is the
    one about z, bit for bit, and nothing is said."""
    xyz = spinning_sweep(rings=16, cols=720, keep=0.8, seed=5, del_=1.0)[0]
    slight, _ = tilt(xyz, 0.5, 30.0)
    org = Organizer()
    scan = org.scan(slight)
    assert org.rotation is None and scan.sensor.mount is None
    assert scan.meta["organize"]["warnings"] == []
    off = Organizer(find_spin_axis=False).scan(slight)
    np.testing.assert_array_equal(scan.point_slot, off.point_slot)
    np.testing.assert_array_equal(scan.ranges, off.ranges)


def test_a_spin_axis_beyond_the_search_is_said_not_guessed():
    """30 deg off z (beyond SPIN_AXIS_MAX_TILT_DEG): the best axis of the search lies on its edge,
    so nothing is concluded; the sweep is organised about z with a warning saying why."""
    from data_tools.organize import SPIN_AXIS_MAX_TILT_DEG, estimate_spin_axis

    xyz = spinning_sweep(rings=16, cols=720, keep=0.8, seed=5, del_=1.0)[0]
    far, _ = tilt(xyz, SPIN_AXIS_MAX_TILT_DEG + 10.0, 60.0)
    assert np.isnan(estimate_spin_axis(far)[1])
    org = Organizer()
    scan = org.scan(far)
    assert org.rotation is None
    assert any("mounted on its side" in w for w in scan.meta["organize"]["warnings"])


def test_organised_cloud_with_every_other_beam_off_keeps_neighbouring_beams_together():
    """An organised cloud (Ouster driver) of a sensor with every other beam off (a reduced-beam
    mode): interleaved, the empty rows left PRC no row neighbours and every return was noise; they
    go after the others, said once per sweep, and PRC labels the sweep as it does the sensor with
    those beams only."""
    from prc_slam.config import PRCConfig
    from prc_slam.prc import classify_scan

    sim_mod = pytest.importorskip("data_tools.sim.simulator")
    sim = sim_mod.Simulator(sim_mod.SimConfig(scene="urban", sensor="hdl64", frames=1))
    f = sim.frame(0)
    grid = sim.sensor.model.to_xyz(f.ranges)
    half = grid.copy()
    half[1::2] = 0.0  # every other beam off
    scan = Organizer().scan_organized(half)
    assert any("hold no return between rows that do" in w for w in scan.meta["organize"]["warnings"])
    rows_with_returns = np.flatnonzero((scan.ranges > 0).any(axis=1))
    np.testing.assert_array_equal(rows_with_returns, np.arange(32))  # the 32 beams on, together at the top
    assert np.all(np.diff(scan.sensor.altitude[:32]) < 0)
    alone = Organizer().scan_organized(grid[0::2].copy())  # the sensor with those 32 beams only
    cfg = PRCConfig.preset("multibeam")
    on = np.repeat(np.arange(half.shape[0]) % 2 == 0, half.shape[1])  # the points of the beams on
    np.testing.assert_array_equal(
        scan.per_point(classify_scan(scan, cfg))[on], alone.per_point(classify_scan(alone, cfg))
    )
    assert scan.n_points == half.shape[0] * half.shape[1]


def test_a_sweep_without_a_return_after_others_keeps_its_place():
    """An empty message or a blocked sensor mid-sequence: the sequence's range image, every slot
    empty, every input point (NaN ones too) in an empty slot (label 0); it is not skipped. Before
    any sweep with a return there is no geometry to give it: an error (the frame is skipped)."""
    xyz = spinning_sweep(rings=8, cols=360, seed=2)[0]
    with pytest.raises(DataError, match="no point with a return"):
        Organizer().scan(np.full((20, 3), np.nan, np.float32))
    org = Organizer()
    first = org.scan(xyz)
    blocked = org.scan(np.full((40, 3), np.nan, np.float32), source="blocked")
    assert blocked.shape == first.shape and not blocked.valid.any()
    assert blocked.n_points == 40
    np.testing.assert_array_equal(blocked.per_point(np.full(blocked.shape, 5, np.uint8) * blocked.valid), 0)
    assert any("an empty sweep" in w for w in blocked.meta["organize"]["warnings"])
    nothing = org.scan(np.zeros((0, 3), np.float32))
    assert nothing.n_points == 0 and nothing.shape == first.shape
    assert org.scan(xyz).meta["organize"]["rings"] == 8  # and the sequence goes on


def test_a_map_tile_is_not_taken_for_a_sweep():
    """A flat 80 x 80 m tile of points seen from its corner (a map cloud given to a sweep
    command): the azimuth steps between its points imply hundreds of thousands of columns a turn;
    it is refused in one line (it built a 158 x 360,391 range image, 16 s and 675 MB)."""
    g = np.random.default_rng(0).uniform(0.0, 80.0, (30000, 2))
    tile = np.column_stack([g, np.random.default_rng(1).normal(0.0, 0.02, 30000)]).astype(np.float32)
    with pytest.raises(DataError, match="columns per turn, more than any spinning sensor"):
        Organizer().scan(tile, source="tile")


def test_the_spin_axis_is_found_on_the_first_sweep_with_points():
    """A first sweep without returns (skipped) does not settle the spin axis: the next one does."""
    xyz = spinning_sweep(rings=16, cols=720, keep=0.8, seed=5, del_=1.0)[0]
    tilted, _ = tilt(xyz, 5.0, 10.0)
    org = Organizer()
    with pytest.raises(DataError, match="no point with a return"):
        org.scan(np.full((2000, 3), np.nan, np.float32))
    scan = org.scan(tilted)
    assert org.spin_tilt_deg == pytest.approx(5.0, abs=0.1)
    assert any("from the points' z axis" in w for w in scan.meta["organize"]["warnings"])
