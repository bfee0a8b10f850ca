"""ROS 1/2 bags and MCAP: PointCloud2 decoding, the three driver layouts read back from simulated
sweeps (slots and PRC labels vs the simulator's range image), the filtered stream written back
(round trip), and one-line errors for bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data_tools import open_dataset
from data_tools.datasets import detect_format
from data_tools.errors import DataError
from data_tools.formats.rosbag import (
    CloudMessage,
    Field,
    RosbagSequence,
    cloud_from_records,
    decode_cloud,
    time_unit,
)
from data_tools.formats.stream_out import RosCloudWriter, open_stream_writer
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam.config import Config
from prc_slam.filtering import choose_points, parse_keep_labels
from prc_slam.jobs.filter import run_filter
from prc_slam.pipeline import classify_frames
from prc_slam.prc.config import PRCConfig
from prc_slam.scan import Scan
from tests.messages import one_line

EPOCH = 1_700_000_000  # s; recordings carry epoch stamps
TOPIC = "/points"

# --------------------------------------------------------------------------------------------
# the three driver layouts, built from simulated sweeps

VELODYNE = np.dtype(  # velodyne_pointcloud PointXYZIRT, packed (point_step 22)
    {
        "names": ["x", "y", "z", "intensity", "ring", "time"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
        "offsets": [0, 4, 8, 12, 16, 18],
        "itemsize": 22,
    }
)
OUSTER = np.dtype(  # ouster_ros PointOS (point_step 48, padding after z)
    {
        "names": ["x", "y", "z", "intensity", "t", "reflectivity", "ring", "ambient", "range"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
        "offsets": [0, 4, 8, 16, 20, 24, 26, 28, 32],
        "itemsize": 48,
    }
)
NO_RING = np.dtype(  # a driver without ring: x y z intensity and an absolute double timestamp
    {
        "names": ["x", "y", "z", "intensity", "timestamp"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<f8"],
        "offsets": [0, 4, 8, 12, 16],
        "itemsize": 24,
    }
)


def vlp16_firing_rows(rows: int) -> np.ndarray:
    """VLP-16 laser firing order (elevations -15, 1, -13, 3, ...) as image rows (top beam first)."""
    elev = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15])
    assert rows == 16
    return ((15 - elev) // 2).astype(np.int64)


def firing_order(ranges: np.ndarray, rows_in_column: np.ndarray) -> np.ndarray:
    """Flat slot indices of the returns, column after column, rows in firing order."""
    cols = ranges.shape[1]
    slots = (rows_in_column[None, :] * cols + np.arange(cols)[:, None]).reshape(-1)
    return slots[ranges.reshape(-1)[slots] > 0]


def velodyne_cloud(frame, model) -> tuple[CloudMessage, np.ndarray]:
    """Unorganised, firing order, ring (0 = lowest beam) and time (s, relative to the stamp at the
    end of the sweep, so negative). Returns the cloud and the simulator slot of every point."""
    slots = firing_order(frame.ranges, vlp16_firing_rows(model.rows))
    xyz = model.to_xyz(frame.ranges).reshape(-1, 3)[slots]
    stamp = EPOCH + float(frame.slot_times.max())
    rec = np.zeros(len(slots), VELODYNE)
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["intensity"] = frame.intensity.reshape(-1)[slots]
    rec["ring"] = model.rows - 1 - slots // model.cols
    rec["time"] = (EPOCH + frame.slot_times.reshape(-1)[slots]) - stamp
    return cloud_from_records(rec, frame_id="velodyne", stamp_ns=round(stamp * 1e9), seq=frame.index), slots


def ouster_cloud(frame, model) -> tuple[CloudMessage, np.ndarray]:
    """Organised H x W (H = beams, top first), no return = zeros, t (ns from the stamp at the
    sweep start), ring = row."""
    rows, cols = model.rows, model.cols
    t0 = EPOCH + float(frame.slot_times.min())
    rec = np.zeros(rows * cols, OUSTER)
    xyz = model.to_xyz(frame.ranges).reshape(-1, 3)
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["intensity"] = frame.intensity.reshape(-1)
    rec["t"] = np.round((EPOCH + frame.slot_times.reshape(-1) - t0) * 1e9).astype(np.uint32)
    rec["ring"] = np.repeat(np.arange(rows), cols)
    rec["range"] = np.round(frame.ranges.reshape(-1) * 1000).astype(np.uint32)
    cloud = cloud_from_records(rec, height=rows, frame_id="os_sensor", stamp_ns=round(t0 * 1e9))
    return cloud, np.arange(rows * cols)


def no_ring_cloud(frame, model) -> tuple[CloudMessage, np.ndarray]:
    """Unorganised, firing order (column after column, top to bottom), no ring, absolute
    timestamps (s, float64)."""
    slots = firing_order(frame.ranges, np.arange(model.rows))
    xyz = model.to_xyz(frame.ranges).reshape(-1, 3)[slots]
    rec = np.zeros(len(slots), NO_RING)
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["intensity"] = frame.intensity.reshape(-1)[slots]
    rec["timestamp"] = EPOCH + frame.slot_times.reshape(-1)[slots]
    stamp = EPOCH + float(frame.slot_times.min())
    return cloud_from_records(rec, frame_id="lidar", stamp_ns=round(stamp * 1e9)), slots


LAYOUTS = {
    "velodyne": ("vlp16", velodyne_cloud),
    "ouster": ("hdl64", ouster_cloud),
    "no_ring": ("hdl64", no_ring_cloud),
}


@pytest.fixture(scope="module")
def sims() -> dict[str, tuple]:
    """Two simulated sweeps per sensor (frames 2 and 3: the vehicle is moving)."""
    out = {}
    for sensor in ("vlp16", "hdl64"):
        sim = Simulator(SimConfig(sensor=sensor, frames=4, seed=2))
        out[sensor] = (sim.sensor.model, [sim.frame(i) for i in (2, 3)])
    return out


def write_bag(path, kind: str, clouds: list[CloudMessage], topic: str = TOPIC) -> None:
    with RosCloudWriter(path, kind, topic) as w:
        for c in clouds:
            w.write_cloud(c)


@pytest.fixture(scope="module")
def layout_bags(sims, tmp_path_factory) -> dict[str, tuple]:
    """Per layout: an .mcap recording, the clouds, the simulator slots, the model and frames."""
    root = tmp_path_factory.mktemp("bags")
    out = {}
    for name, (sensor, build) in LAYOUTS.items():
        model, frames = sims[sensor]
        built = [build(f, model) for f in frames]
        path = root / f"{name}.mcap"
        write_bag(path, "mcap", [c for c, _ in built])
        out[name] = (path, built, model, frames)
    return out


def reference_labels(model, frames) -> list[np.ndarray]:
    """PRC labels per slot on the simulator's own range images."""
    scans = [Scan(ranges=f.ranges, sensor=model, name=f"{f.index:06d}") for f in frames]
    return [cf.labels for cf in classify_frames(scans, PRCConfig())]


def slot_agreement(scan: Scan, truth_slots: np.ndarray, valid: np.ndarray, sim_shape: tuple[int, int]) -> float:
    """Share of the points with a return that are in their simulator slot: same row, same
    column up to one global cyclic shift (and direction) of the columns, which changes no
    neighbourhood."""
    if scan.shape != sim_shape:
        return 0.0
    rows, cols = sim_shape
    slots = scan.point_slot if scan.point_slot is not None else np.arange(rows * cols)
    r_o, c_o = np.divmod(np.asarray(slots)[valid], cols)
    r_s, c_s = np.divmod(truth_slots[valid], cols)
    best = 0.0
    for sign in (1, -1):
        shift = np.bincount((c_o - sign * c_s) % cols, minlength=cols).argmax()
        ok = (r_o == r_s) & (c_o == (sign * c_s + shift) % cols)
        best = max(best, float(ok.mean()))
    return best


# --------------------------------------------------------------------------------------------
# decoding


def test_decode_honours_offsets_padding_and_byte_order():
    """A hand-built big-endian cloud with row padding and a 2-element field."""
    dt = np.dtype(
        {
            "names": ["z", "x", "y", "rgb2", "ring"],
            "formats": [">f8", ">f4", ">f4", (">u2", (2,)), ">u2"],
            "offsets": [0, 8, 12, 16, 20],
            "itemsize": 24,
        }
    )
    rec = np.zeros(6, dt)
    rec["x"], rec["y"], rec["z"] = [1, 2, 3, 4, 5, 6], [-1, -2, -3, -4, -5, -6], [0.5, 1.5, 2.5, 3.5, 4.5, 5.5]
    rec["ring"] = [7, 8, 9, 10, 11, 12]
    rows = rec.view(np.uint8).reshape(2, 3 * 24)
    data = np.concatenate([rows, np.full((2, 5), 0xEE, np.uint8)], axis=1).reshape(-1)  # 5 padding bytes per row

    class Stamp:
        sec, nanosec = 12, 500_000_000

    class Header:
        stamp, frame_id = Stamp, "f"

    class PF:
        def __init__(self, name, offset, datatype, count):
            self.name, self.offset, self.datatype, self.count = name, offset, datatype, count

    class Msg:
        header, height, width, point_step, row_step = Header, 2, 3, 24, 3 * 24 + 5
        is_bigendian, is_dense = True, True

    Msg.fields = [PF("z", 0, 8, 1), PF("x", 8, 7, 1), PF("y", 12, 7, 1), PF("rgb2", 16, 4, 2), PF("ring", 20, 4, 1)]
    Msg.data = data
    cloud = decode_cloud(Msg, "hand.bag#/p[0]")
    assert cloud.stamp == 12.5 and cloud.height == 2 and cloud.width == 3
    np.testing.assert_array_equal(cloud.points["x"], [1, 2, 3, 4, 5, 6])
    np.testing.assert_array_equal(cloud.points["z"], [0.5, 1.5, 2.5, 3.5, 4.5, 5.5])
    np.testing.assert_array_equal(cloud.points["ring"], [7, 8, 9, 10, 11, 12])
    assert cloud.raw.shape == (6, 24)
    Msg.fields = [Msg.fields[0], PF("x", 8, 9, 1), *Msg.fields[2:]]  # unknown datatype
    with pytest.raises(DataError, match=r"hand\.bag.*unknown PointField datatype"):
        decode_cloud(Msg, "hand.bag#/p[0]")


@settings(max_examples=60, deadline=None)
@given(
    period=st.floats(0.02, 0.25),
    fill=st.floats(0.8, 1.0),
    unit=st.sampled_from(["s", "ms", "us", "ns"]),
    offset=st.floats(-0.2, 0.2),
)
def test_time_unit_is_the_one_matching_the_sweep_period(period, fill, unit, offset):
    scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[unit]
    values = (offset + np.linspace(0.0, period * fill, 500)) / scale
    if unit in ("us", "ns"):
        values = np.round(values).astype(np.int64)
    assert time_unit(values, period)[0] == unit


def test_time_unit_without_period_follows_the_datatype():
    assert time_unit(np.array([0.0, 0.05], np.float32), None) == ("s", 1.0)
    assert time_unit(np.array([0, 50_000_000], np.uint32), None) == ("ns", 1e-9)


# --------------------------------------------------------------------------------------------
# the three layouts read back


@pytest.mark.parametrize(
    "layout",
    [
        "velodyne",
        "ouster",
        "no_ring",
    ],
)
def test_layout_read_back_slots_times_and_prc_labels(layout, layout_bags):
    path, built, model, frames = layout_bags[layout]
    assert detect_format(path) == "rosbag"
    seq = open_dataset(path)
    assert len(seq) == len(frames) and seq.topic == TOPIC
    np.testing.assert_allclose(seq.times, [c.stamp for c, _ in built], atol=1e-9)
    refs = reference_labels(model, frames)
    got = list(classify_frames(seq, PRCConfig()))
    assert len(got) == len(frames)
    for (cloud, truth), frame, ref, cf in zip(built, frames, refs, got, strict=True):
        scan = cf.scan
        n = cloud.height * cloud.width
        assert scan.n_points == n
        valid = frame.ranges.reshape(-1)[truth] > 0
        times = scan.point_times()
        assert times is not None and times.shape == (n,)
        err = np.abs(times - (EPOCH + frame.slot_times.reshape(-1)[truth]))[valid]
        assert err.max() < 2e-6, f"{layout}: per-point time off by {err.max():.2e} s"
        slots = slot_agreement(scan, truth, valid, frame.ranges.shape)
        assert slots >= 0.99, f"{layout}: {slots:.4f} of points in their simulator slot"
        labels = cf.point_labels()
        assert labels.shape == (n,)
        assert (labels[~valid] == 0).all()  # no returns: label no_return
        same = (labels == ref.reshape(-1)[truth])[valid].mean()
        assert same >= 0.99, f"{layout}: PRC labels equal on {same:.4f} of points"


def test_getitem_seeks_the_same_frame_as_iteration(layout_bags):
    path, built, _model, _frames = layout_bags["velodyne"]
    seq = RosbagSequence(path)
    second = seq[1]
    assert second.meta["ros"].stamp == built[1][0].stamp
    np.testing.assert_array_equal(second.meta["ros"].raw, built[1][0].raw)
    assert seq[-1].name == second.name == "000001"
    with pytest.raises(IndexError):
        seq[2]


# --------------------------------------------------------------------------------------------
# the filtered stream: round trip


@pytest.mark.parametrize("kind", ["mcap", "ros2", "ros1"])
def test_filter_round_trip_is_exact(kind, layout_bags, tmp_path):
    _path, built, _model, _frames = layout_bags["velodyne"]
    src = tmp_path / {"mcap": "in.mcap", "ros2": "in_ros2", "ros1": "in.bag"}[kind]
    write_bag(src, kind, [c for c, _ in built])
    seq = open_dataset(src)
    assert seq.kind == kind
    config = Config()
    expected = []
    for cf in classify_frames(seq, config.prc):
        labels = cf.point_labels()
        keep = choose_points(cf.scan.points(), labels, config.filter, one_sided=cf.point_one_sided())
        expected.append((cf.scan.meta["ros"], keep, labels))
    out = tmp_path / {"mcap": "out.mcap", "ros2": "out_ros2", "ros1": "out.bag"}[kind]
    ticks = []
    metrics = run_filter(open_dataset(src), out, config, progress=lambda i, n: ticks.append((i, n)))
    assert ticks == [(1, 2), (2, 2)] and metrics["out_format"] == kind
    back = RosbagSequence(out)
    assert back.kind == kind and back.topic == TOPIC and len(back) == len(expected)
    kept_total = 0
    for (_t, cloud), (src_cloud, keep, labels) in zip(back.clouds(), expected, strict=True):
        assert cloud.frame_id == src_cloud.frame_id
        assert (cloud.stamp_sec, cloud.stamp_nanosec) == (src_cloud.stamp_sec, src_cloud.stamp_nanosec)
        assert cloud.names == (*src_cloud.names, "label") and cloud.height == 1
        step = src_cloud.point_step
        np.testing.assert_array_equal(cloud.raw[:, :step], src_cloud.raw[keep])
        np.testing.assert_array_equal(cloud.points["label"], labels[keep])
        kept_total += int(keep.sum())
    assert metrics["points_kept"] == kept_total
    assert metrics["points_in"] == sum(c.width for c, _ in built)
    per = metrics["per_class"]
    assert sum(v["in"] for v in per.values()) == metrics["points_in"]
    assert per.get("noise", {"kept": 0})["kept"] <= per.get("noise", {"in": 0})["in"]
    assert 0 < per["ground"]["kept"] < per["ground"]["in"]  # ground thinned, not removed


def test_filter_organised_cloud_drops_no_returns_and_keeps_labels(layout_bags, tmp_path):
    path, _built, _model, _frames = layout_bags["ouster"]
    out = tmp_path / "f.mcap"
    metrics = run_filter(open_dataset(path), out, Config(), keep_labels=["building", "vegetation"])
    assert metrics["keep_labels"] == ["vegetation", "building"]
    back = RosbagSequence(out)
    for _t, cloud in back.clouds():
        assert set(np.unique(cloud.points["label"])) <= {5, 6}
        assert (cloud.points["range"] > 0).all()  # no-return (zero) points never written
    assert metrics["per_class"]["no_return"]["kept"] == 0


def test_filter_to_pcd_and_kitti_folders(layout_bags, tmp_path):
    import open3d as o3d

    path, _built, _model, _frames = layout_bags["velodyne"]
    m_pcd = run_filter(open_dataset(path), tmp_path / "pcd", Config(), out_format="pcd")
    pcds = sorted((tmp_path / "pcd").glob("*.pcd"))
    assert len(pcds) == 2 and (tmp_path / "pcd" / "times.txt").is_file()
    total = 0
    for p in pcds:
        pc = o3d.t.io.read_point_cloud(str(p))
        pos = pc.point.positions.numpy()
        assert pc.point["label"].numpy().shape[0] == len(pos) and "time" in pc.point
        total += len(pos)
    assert total == m_pcd["points_kept"]
    m_kitti = run_filter(open_dataset(path), tmp_path / "kitti", Config(), out_format="kitti")
    seq = open_dataset(tmp_path / "kitti", "kitti") if (tmp_path / "kitti" / "poses.txt").exists() else None
    bins = sorted((tmp_path / "kitti" / "velodyne").glob("*.bin"))
    sizes = [p.stat().st_size // 16 for p in bins]
    labels = [np.fromfile(p, np.uint32) for p in sorted((tmp_path / "kitti" / "labels").glob("*.label"))]
    assert sum(sizes) == m_kitti["points_kept"] == m_pcd["points_kept"] and [len(x) for x in labels] == sizes
    assert seq is None  # a recording has no poses: none written


def test_bag_output_needs_a_recording(tmp_path, sims):
    model, frames = sims["vlp16"]
    scans = [Scan(ranges=frames[0].ranges, sensor=model, name="000000")]

    class Seq(list):
        format = "sim"
        poses = None

    with pytest.raises(DataError, match="output format mcap needs a ROS 1/2 or MCAP input"):
        open_stream_writer(tmp_path / "x.mcap", Seq(scans))


def test_keep_labels_parsing():
    assert parse_keep_labels("ground, 6") == [2, 6]
    assert parse_keep_labels(None) is None
    with pytest.raises(ValueError, match="unknown label 'tree'"):
        parse_keep_labels(["tree"])


# --------------------------------------------------------------------------------------------
# bad input: one-line errors naming the file


def test_recording_without_pointcloud2(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    path = tmp_path / "imu_only"
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        w.write(conn, 1, ts.serialize_cdr(ts.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"))
    with pytest.raises(DataError) as exc:
        open_dataset(path)
    assert "no sensor_msgs/PointCloud2 topic" in one_line(exc, path) and "/chatter" in str(exc.value)


def test_two_cloud_topics_need_a_topic(tmp_path, layout_bags):
    _p, built, _m, _f = layout_bags["velodyne"]
    path = tmp_path / "two.bag"
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    with RosCloudWriter(tmp_path / "one.bag", "ros1", "/a") as w:
        w.write_cloud(built[0][0])
    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer(path) as w:
        src = RosbagSequence(tmp_path / "one.bag")
        raw = next(src._reader.messages())[2]
        for topic in ("/front", "/rear"):
            conn = w.add_connection(topic, "sensor_msgs/msg/PointCloud2", typestore=ts)
            w.write(conn, 10, raw)
    with pytest.raises(DataError) as exc:
        open_dataset(path)
    text = one_line(exc, path)
    assert "/front" in text and "/rear" in text and "--topic" in text
    seq = open_dataset(path, topic="/rear")
    assert seq.topic == "/rear" and len(seq) == 1


@pytest.mark.parametrize("suffix", [".bag", ".mcap", ".db3"])
def test_truncated_recording(tmp_path, layout_bags, suffix):
    _p, built, _m, _f = layout_bags["velodyne"]
    kind = {".bag": "ros1", ".mcap": "mcap", ".db3": "ros2"}[suffix]
    full = tmp_path / ("full" + (suffix if suffix != ".db3" else ""))
    write_bag(full, kind, [c for c, _ in built])
    data = (full / "full.db3" if suffix == ".db3" else full).read_bytes()
    path = tmp_path / f"cut{suffix}"
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(DataError) as exc:
        seq = open_dataset(path)
        list(seq)
    assert "truncated" in one_line(exc, path)


def test_cloud_missing_x(tmp_path):
    rec = np.zeros(10, np.dtype([("a", "<f4"), ("y", "<f4"), ("z", "<f4")]))
    path = tmp_path / "nox.mcap"
    write_bag(path, "mcap", [cloud_from_records(rec, stamp_ns=EPOCH * 10**9)])
    with pytest.raises(DataError) as exc:
        list(open_dataset(path))
    assert "no x field" in one_line(exc, path)


def test_field_outside_point_step_is_an_error():
    rec = np.zeros(4, np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")]))
    cloud = cloud_from_records(rec)
    bad = CloudMessage(**{**cloud.__dict__, "fields": (*cloud.fields, Field("t", 10, 6, 1))})
    from data_tools.formats.rosbag import fields_dtype

    with pytest.raises(DataError, match="outside point_step 12"):
        fields_dtype(bad.fields, bad.point_step, False, "x.bag")


def test_filter_sink_in_the_pipeline_writes_what_run_filter_writes(layout_bags, tmp_path):
    from prc_slam.jobs.filter import FilterSink
    from prc_slam.pipeline import Pipeline

    path, _built, _model, _frames = layout_bags["velodyne"]
    config = Config()
    a = run_filter(open_dataset(path), tmp_path / "a.mcap", config)
    sink = FilterSink(open_stream_writer(tmp_path / "b.mcap", open_dataset(path)), config.filter)
    Pipeline(prc=config.prc, sinks=[sink]).run(open_dataset(path))
    b = sink.metrics()
    assert b["per_class"] == a["per_class"] and b["frames"] == a["frames"] == 2
    for (_ta, ca), (_tb, cb) in zip(
        RosbagSequence(tmp_path / "a.mcap").clouds(), RosbagSequence(tmp_path / "b.mcap").clouds(), strict=True
    ):
        np.testing.assert_array_equal(ca.raw, cb.raw)


def test_pcd_folder_in_pcd_folder_out_keeps_the_input_fields(layout_bags, tmp_path):
    from data_tools.formats.pcd import read_pcd, write_pcd

    _path, built, _model, _frames = layout_bags["velodyne"]
    src = tmp_path / "sweeps"
    for i, (cloud, _slots) in enumerate(built):
        write_pcd(src / f"{i:06d}.pcd", {name: cloud.points[name] for name in cloud.names})
    seq = open_dataset(src)
    assert seq.format == "pcd"
    m = run_filter(seq, tmp_path / "out", Config())
    assert m["out_format"] == "pcd" and m["frames"] == 2
    expected = [
        choose_points(cf.scan.points(), cf.point_labels(), Config().filter, one_sided=cf.point_one_sided())
        for cf in classify_frames(open_dataset(src), Config().prc)
    ]
    for (cloud, _slots), keep, out in zip(built, expected, sorted((tmp_path / "out").glob("*.pcd")), strict=True):
        fields, _shape = read_pcd(out)
        assert list(fields) == [*cloud.names, "label"]
        for name in cloud.names:
            np.testing.assert_array_equal(fields[name], cloud.points[name][keep])


def test_real_ouster_sweeps_as_an_ouster_ros_bag_classify_like_the_npz_reader(ouster_files, tmp_path):
    """The shared OS-0/OS-1/OS-2 sweeps written as the Ouster ROS driver publishes them (organised,
    destaggered, zeros for no return, t in ns, ring): PRC labels as from the decoded npz reader
    (destaggered) on >= 99 % of returns (the bag's ranges come from xyz, the npz's from range_mm)."""
    from data_tools.formats.ouster import destagger, read_ouster_npz

    for f in ouster_files[:: max(1, len(ouster_files) // 2)]:
        with np.load(f) as z:
            shift, ts = z["pixel_shift_by_row"], z["column_ts_ns"].astype(np.int64)
            rng = destagger(z["range_mm"], shift)
            xyz = destagger(z["xyz_lidar_m"], shift)
        rows, cols = rng.shape
        ok = (rng > 0).reshape(-1)
        rec = np.zeros(rows * cols, OUSTER)
        rec["x"], rec["y"], rec["z"] = np.where(ok[:, None], xyz.reshape(-1, 3), 0).T
        rec["t"] = (destagger(np.broadcast_to(ts[None, :], rng.shape), shift) - ts.min()).reshape(-1)
        rec["ring"] = np.repeat(np.arange(rows), cols)
        rec["range"] = rng.reshape(-1)
        path = tmp_path / f"{f.stem}.mcap"
        write_bag(path, "mcap", [cloud_from_records(rec, height=rows, frame_id="os_sensor", stamp_ns=int(ts.min()))])
        got = next(iter(classify_frames(open_dataset(path), PRCConfig())))
        ref = next(iter(classify_frames([read_ouster_npz(f, destaggered=True)], PRCConfig())))
        assert got.scan.meta["organize"]["warnings"] == []
        same = (got.point_labels()[ok] == ref.labels.reshape(-1)[ok]).mean()
        assert same >= 0.99, f"{f.name}: PRC labels equal on {same:.4f} of returns"


def test_organised_cloud_whose_rows_are_firings_is_organised_by_its_ring_field(sims, tmp_path):
    """height = columns, width = beams (one firing per row): the ring field varies along a row,
    so the rows are not beams; the points are organised from the ring field instead."""
    model, frames = sims["hdl64"]
    frame = frames[0]
    cloud, _ = ouster_cloud(frame, model)
    rows, cols = model.rows, model.cols
    firing = cloud.points.reshape(rows, cols).T.copy()  # (cols, rows): one firing per row
    path = tmp_path / "transposed.mcap"
    write_bag(path, "mcap", [cloud_from_records(firing.reshape(-1), height=cols, stamp_ns=EPOCH * 10**9)])
    scan = open_dataset(path)[0]
    assert scan.meta["organize"]["method"] == "ring-field" and scan.shape == (rows, cols)
    truth = (np.arange(rows)[None, :] * cols + np.arange(cols)[:, None]).reshape(-1)
    valid = frame.ranges.reshape(-1)[truth] > 0
    assert (scan.point_slot[valid] // cols == truth[valid] // cols).all()  # every return on its beam's row


def test_time_fields_absolute_seconds_and_relative_nanoseconds():
    """Hesai-style absolute float64 seconds and Livox-style ``offset_time`` (uint32 ns from the stamp)."""
    from data_tools.formats.rosbag import detect_time_field

    stamp_ns = 1_700_000_000_250_000_000
    offsets = np.arange(0, 100_000_000, 1_000_000, dtype=np.uint32)  # 0 .. 99 ms
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    hesai = np.zeros(len(offsets), np.dtype([*fields, ("timestamp", "<f8")]))
    hesai["timestamp"] = stamp_ns * 1e-9 + offsets * 1e-9
    livox = np.zeros(len(offsets), np.dtype([*fields, ("offset_time", "<u4")]))
    livox["offset_time"] = offsets
    expected = 0.25 + offsets * 1e-9
    for rec, unit, absolute in ((hesai, "s", True), (livox, "ns", False)):
        cloud = cloud_from_records(rec, stamp_ns=stamp_ns)
        tf = detect_time_field(cloud, period=0.1)
        assert (tf.unit, tf.absolute) == (unit, absolute)
        np.testing.assert_allclose(tf.seconds(cloud) - 1_700_000_000, expected, atol=1e-6)
    zero = np.zeros(10, np.dtype([*fields, ("t", "<u4")]))
    assert detect_time_field(cloud_from_records(zero, stamp_ns=stamp_ns), period=0.1) is None  # unset: ignored


def test_a_bad_message_fails_its_frame_only(layout_bags, tmp_path):
    """Message 1 of 3 has no x field: iteration raises for it and goes on (the Pipeline skips it)."""
    from prc_slam.pipeline import Pipeline

    _p, built, _m, _f = layout_bags["velodyne"]
    first, last = built[0][0], built[1][0]
    between = round((first.stamp + last.stamp) / 2 * 1e9)
    bad = cloud_from_records(np.zeros(10, np.dtype([("a", "<f4"), ("y", "<f4"), ("z", "<f4")])), stamp_ns=between)
    path = tmp_path / "mixed.bag"
    write_bag(path, "ros1", [first, bad, last])
    it = iter(open_dataset(path))
    assert next(it).name == "000000"
    with pytest.raises(DataError, match=r"mixed\.bag#/points\[1\]: PointCloud2 has no x field"):
        next(it)
    assert next(it).name == "000002"
    with pytest.raises(StopIteration):
        next(it)
    result = Pipeline(prc=PRCConfig()).run(open_dataset(path))
    assert result.frames == 2 and len(result.skipped) == 1
