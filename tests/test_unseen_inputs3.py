"""Velodyne captures and recordings the project did not read at first: each test generates a small
input in ``tmp_path`` and checks that the readers decode it right, or say clearly why they cannot.

Velodyne captures as they come off a real network (simulated VLP-16 data packets, see
``tests/test_pcap.py``):

- pcapng instead of pcap (Wireshark's default) was taken for an Ouster capture ("no Ouster sensor
  metadata"); so was a capture whose first 64 UDP packets were other traffic;
- 1206-byte UDP packets of another kind on another port went to the decoder, which then failed
  ("Data is from a HDL-64E ...");
- two Velodyne sensors in one capture were decoded as one (their packets interleaved into one
  sweep, half the points in the wrong place, no warning);
- a capture cut inside a record header lost every sweep ("cannot read pcap (truncated?)").
"""

from __future__ import annotations

import logging
import struct
from pathlib import Path

import numpy as np
import pytest

from data_tools import DataError, open_dataset
from data_tools.datasets import detect_format
from tests.test_pcap import vlp16_stream

# --------------------------------------------------------------------------------------------
# packet captures


def eth_udp(payload: bytes, port: int, src: tuple[int, int, int, int] = (192, 168, 1, 201), proto: int = 17) -> bytes:
    """An Ethernet / IPv4 frame around a UDP datagram (or around ``payload`` as is for another protocol)."""
    body = struct.pack(">HHHH", port, port, 8 + len(payload), 0) + payload if proto == 17 else payload
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(body), 0, 0, 64, proto, 0, bytes(src), b"\xff" * 4) + body
    return b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x01" + b"\x08\x00" + ip


def write_pcap(
    path: Path, frames: list[tuple[float, bytes]], *, nano: bool = False, big: bool = False, link: int = 1
) -> Path:
    """Classic libpcap, micro- or nanosecond stamps, either byte order (``link``: the frames' link type)."""
    e = ">" if big else "<"
    with path.open("wb") as f:
        f.write(struct.pack(e + "IHHiIII", 0xA1B23C4D if nano else 0xA1B2C3D4, 2, 4, 0, 0, 65535, link))
        for s, eth in frames:
            frac = round(s % 1 * (1e9 if nano else 1e6))
            f.write(struct.pack(e + "IIII", int(s), frac, len(eth), len(eth)) + eth)
    return path


def write_pcapng(path: Path, frames: list[tuple[float, bytes]], *, tsresol: int | None = None) -> Path:
    """pcapng: section header, one Ethernet interface (``if_tsresol`` 10^-tsresol s when given),
    one enhanced packet block per frame."""

    def block(btype: int, body: bytes) -> bytes:
        body += b"\x00" * (-len(body) % 4)
        return struct.pack("<II", btype, 12 + len(body)) + body + struct.pack("<I", 12 + len(body))

    unit = 10.0 ** -(tsresol or 6)
    options = b"" if tsresol is None else struct.pack("<HHB3x", 9, 1, tsresol) + struct.pack("<HH", 0, 0)
    with path.open("wb") as f:
        f.write(block(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1)))
        f.write(block(1, struct.pack("<HHI", 1, 0, 65535) + options))
        for s, eth in frames:
            ts = round(s / unit)
            f.write(block(6, struct.pack("<IIIII", 0, ts >> 32, ts & 0xFFFFFFFF, len(eth), len(eth)) + eth))
    return path


@pytest.fixture(scope="module")
def vlp16_frames() -> list[tuple[float, bytes]]:
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    payloads, stamps, _ = vlp16_stream(n_sweeps=2.3)
    return [(s, eth_udp(p, 2368)) for p, s in zip(payloads, stamps, strict=True)]


@pytest.fixture(scope="module")
def reference(vlp16_frames, tmp_path_factory) -> tuple[np.ndarray, list[np.ndarray]]:
    """Sweep stamps and points of the plain capture."""
    ds = open_dataset(write_pcap(tmp_path_factory.mktemp("ref") / "ref.pcap", vlp16_frames))
    return ds.times, [ds.sweep(i)[1] for i in range(len(ds))]


def same_sweeps(ds, reference) -> None:
    times, sweeps = reference
    assert ds.format == "velodyne-pcap" and len(ds) == len(sweeps)
    np.testing.assert_allclose(ds.times, times, rtol=0, atol=2e-6)
    for i, ref in enumerate(sweeps):
        got = ds.sweep(i)[1]
        assert len(got) == len(ref)
        for c in ("x", "y", "z", "ring"):
            np.testing.assert_array_equal(got[c], ref[c])


def gprmc_packet(t: float) -> bytes:
    """A VLP-16 position packet (512 bytes, NMEA GPRMC at byte 206), sent to port 8308."""
    buf = bytearray(512)
    struct.pack_into("<I", buf, 198, int((t % 3600) * 1e6))
    nmea = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\r\n"
    buf[206 : 206 + len(nmea)] = nmea
    return bytes(buf)


@pytest.mark.parametrize("case", ["pcapng", "pcapng_ns", "pcapng_named_pcap", "nano", "bigendian"])
def test_capture_file_formats_decode_the_same_sweeps(case, vlp16_frames, reference, tmp_path):
    """pcapng (micro- or nanosecond stamps, even named .pcap), nanosecond-magic and big-endian
    pcap: the same sweeps as the plain capture."""
    if case.startswith("pcapng"):
        suffix = ".pcap" if case == "pcapng_named_pcap" else ".pcapng"
        path = write_pcapng(tmp_path / f"v{suffix}", vlp16_frames, tsresol=9 if case == "pcapng_ns" else None)
    else:
        path = write_pcap(tmp_path / "v.pcap", vlp16_frames, nano=case == "nano", big=case == "bigendian")
    assert detect_format(path) == "velodyne-pcap"
    same_sweeps(open_dataset(path), reference)


LINK_HEADERS = {  # link type -> header put before the IPv4 packet of an Ethernet frame
    "ethernet_vlan": (1, b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x01" + b"\x81\x00\x00\x05" + b"\x08\x00"),
    "linux_sll": (113, b"\x00\x00\x00\x01\x00\x06" + b"\x60\x76\x88\x00\x00\x01\x00\x00" + b"\x08\x00"),
    "linux_sll2": (
        276,
        b"\x08\x00\x00\x00" + b"\x00\x00\x00\x02" + b"\x00\x01\x00\x06" + b"\x60\x76\x88\x00\x00\x01\x00\x00",
    ),
    "raw_ip": (101, b""),
}


@pytest.mark.parametrize("link", sorted(LINK_HEADERS))
def test_captures_of_other_link_types_decode_the_same_sweeps(link, vlp16_frames, reference, tmp_path):
    """``tcpdump -i any`` writes Linux cooked frames (v2 on current libpcap); VLAN-tagged Ethernet,
    raw IP: the same sweeps (every frame was parsed as Ethernet before)."""
    code, header = LINK_HEADERS[link]
    path = write_pcap(tmp_path / "v.pcap", [(s, header + eth[14:]) for s, eth in vlp16_frames], link=code)
    same_sweeps(open_dataset(path), reference)


def test_other_traffic_is_skipped(vlp16_frames, reference, tmp_path):
    """Position packets on 8308, 300 packets of other UDP traffic before the lidar starts, 1206-byte
    datagrams that are not Velodyne data on another port, TCP and ARP frames: the lidar's sweeps only."""
    rng = np.random.default_rng(0)
    t0 = vlp16_frames[0][0]
    other = [(t0 - 1 + k * 1e-3, eth_udp(rng.bytes(300), 5353)) for k in range(300)]
    other += [(s + 1e-4, eth_udp(gprmc_packet(s), 8308)) for s, _ in vlp16_frames[::40]]
    other += [(s + 5e-5, eth_udp(rng.bytes(1206), 9999)) for s, _ in vlp16_frames[::10]]
    other += [(s + 3e-5, eth_udp(b"\x00" * 40, 0, proto=6)) for s, _ in vlp16_frames[::5]]
    arp = b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x02\x08\x06" + b"\x00" * 28
    other += [(s + 4e-5, arp) for s, _ in vlp16_frames[::7]]
    path = write_pcap(tmp_path / "busy.pcap", sorted(vlp16_frames + other, key=lambda x: x[0]))
    assert detect_format(path) == "velodyne-pcap"
    same_sweeps(open_dataset(path), reference)


def test_two_velodyne_sensors_in_one_capture_are_an_error_naming_both(vlp16_frames, tmp_path):
    payloads, stamps, _ = vlp16_stream(n_sweeps=2.3, seed=5)
    second = [(s + 2e-5, eth_udp(p, 2369, src=(192, 168, 1, 202))) for p, s in zip(payloads, stamps, strict=True)]
    path = write_pcap(tmp_path / "two.pcap", sorted(vlp16_frames + second, key=lambda x: x[0]))
    with pytest.raises(DataError) as exc:
        open_dataset(path)
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg
    assert "192.168.1.201 -> port 2368" in msg and "192.168.1.202 -> port 2369" in msg


def test_a_few_stray_packets_of_another_sensor_are_dropped_with_a_warning(vlp16_frames, reference, tmp_path, caplog):
    stray = [(s + 2e-5, eth_udp(eth[42:], 2368, src=(10, 0, 0, 9))) for s, eth in vlp16_frames[:3]]  # 42: headers
    path = write_pcap(tmp_path / "stray.pcap", sorted(vlp16_frames + stray, key=lambda x: x[0]))
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(path)
    assert any("3 Velodyne data packets from other sources" in r.getMessage() for r in caplog.records)
    same_sweeps(ds, reference)


@pytest.mark.parametrize("cut", [500, 1206 + 42 + 8], ids=["inside_data", "inside_record_header"])
def test_a_truncated_capture_keeps_the_sweeps_before_the_cut(cut, vlp16_frames, reference, tmp_path, caplog):
    full = write_pcap(tmp_path / "full.pcap", vlp16_frames)
    path = tmp_path / "cut.pcap"
    path.write_bytes(full.read_bytes()[:-cut])
    with caplog.at_level(logging.WARNING):
        ds = open_dataset(path)
    assert any("truncated" in r.getMessage() for r in caplog.records)
    _, sweeps = reference
    assert len(ds) == len(sweeps)
    for i in range(len(ds) - 1):  # whole sweeps as before; the last one loses the cut packet only
        np.testing.assert_array_equal(ds.sweep(i)[1]["x"], sweeps[i]["x"])
    assert 0 < len(sweeps[-1]) - len(ds.sweep(len(ds) - 1)[1]) <= 384


def test_a_capture_without_velodyne_packets_is_a_one_line_error(tmp_path):
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    from data_tools.formats.velodyne_pcap import VelodynePcapSequence

    path = write_pcap(tmp_path / "gps.pcap", [(1e9 + k, eth_udp(gprmc_packet(k), 8308)) for k in range(5)])
    with pytest.raises(DataError, match="no Velodyne data packets") as exc:
        VelodynePcapSequence(path)
    assert "\n" not in str(exc.value) and str(path) in str(exc.value)
    bad = tmp_path / "notacapture.pcap"
    bad.write_bytes(b"hello world, this is not a capture at all")
    with pytest.raises(DataError, match="not a pcap or pcapng") as exc:
        VelodynePcapSequence(bad)


@pytest.mark.parametrize("content, message", [(b"", "empty file"), (b"hello\n", "not a pcap or pcapng capture")])
def test_an_empty_or_foreign_pcap_says_so(tmp_path, content, message):
    """It said 'no Ouster sensor metadata: expected ...json beside it'."""
    path = tmp_path / "x.pcap"
    path.write_bytes(content)
    with pytest.raises(DataError, match=message) as exc:
        open_dataset(path)
    assert "Ouster" not in str(exc.value) and str(path) in str(exc.value)


# --------------------------------------------------------------------------------------------
# Ouster captures


def pcap_records(path: Path) -> tuple[int, list[tuple[float, bytes]]]:
    """Link type and (stamp, frame) records of a little-endian microsecond pcap."""
    raw = path.read_bytes()
    assert struct.unpack("<I", raw[:4])[0] == 0xA1B2C3D4
    link, k, out = struct.unpack("<I", raw[20:24])[0], 24, []
    while k + 16 <= len(raw):
        sec, us, incl, _ = struct.unpack("<IIII", raw[k : k + 16])
        out.append((sec + us * 1e-6, raw[k + 16 : k + 16 + incl]))
        k += 16 + incl
    return link, out


def with_ports(frame: bytes, port: int) -> bytes:
    """The Ethernet/IPv4/UDP frame sent from and to ``port``."""
    b = bytearray(frame)
    struct.pack_into(">HH", b, 14 + (b[14] & 0x0F) * 4, port, port)
    return bytes(b)


@pytest.fixture(scope="module")
def ouster_capture() -> tuple[Path, Path]:
    from tests.conftest import SHARED_DATA

    pcap = SHARED_DATA / "ouster" / "pcaps" / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap"
    meta = pcap.with_name("OS-1-128_v2.3.0_1024x10.json")
    if not pcap.is_file() or not meta.is_file():
        pytest.skip(f"Ouster capture not found: {pcap}")
    return pcap, meta


def test_ouster_capture_on_another_port_names_the_ports(ouster_capture, tmp_path):
    """A sensor configured to another UDP port than its json says: the error gives the json's
    port and the capture's ports and packet sizes (it said only 'no lidar packets matching')."""
    pcap, meta = ouster_capture
    _, recs = pcap_records(pcap)
    path = write_pcap(tmp_path / "moved.pcap", [(s, with_ports(f, 7777)) for s, f in recs])
    with pytest.raises(DataError) as exc:
        open_dataset(path, "ouster-pcap", meta=meta)
    msg = str(exc.value)
    assert "\n" not in msg and "udp_port_lidar 7502" in msg and "port 7777: 192 of 8448 bytes" in msg


def test_ouster_capture_with_other_traffic_and_as_pcapng_reads_the_same_sweeps(ouster_capture, tmp_path):
    """Packets of the lidar's size on another port (a second application, mirrored traffic) are
    not lidar packets; pcapng reads as pcap."""
    pcap, meta = ouster_capture
    ref = open_dataset(pcap, "ouster-pcap", meta=meta)
    _, recs = pcap_records(pcap)
    rng = np.random.default_rng(1)
    junk = [(s + 1e-6, eth_udp(rng.bytes(8448), 7600)) for s, _ in recs[::3]]
    mirrored = [(s + 2e-6, with_ports(f, 7777)) for s, f in recs]
    busy = write_pcap(tmp_path / "busy.pcap", sorted(recs + junk + mirrored, key=lambda x: x[0]))
    ng = write_pcapng(tmp_path / "ng.pcapng", recs)
    for path in (busy, ng):
        ds = open_dataset(path, "ouster-pcap", meta=meta)
        assert len(ds) == len(ref) == 3
        np.testing.assert_array_equal(ds.frame_ids, ref.frame_ids)
        for i in range(len(ref)):
            np.testing.assert_array_equal(ds[i].ranges, ref[i].ranges)


# --------------------------------------------------------------------------------------------
# command line: output paths, interruption


@pytest.fixture(scope="module")
def small_kitti(tmp_path_factory) -> Path:
    from data_tools.sim.dataset import SimSequence, export_kitti, write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    sim = tmp_path_factory.mktemp("h30_sim") / "sim"
    write_sequence(Simulator(SimConfig(frames=3, seed=4)), sim)
    out = tmp_path_factory.mktemp("h30_kitti") / "k ü"  # a space and a non-ASCII letter
    export_kitti(SimSequence(sim), out)
    return out


def one_error_line(res) -> str:
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output, res.output
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, res.output
    return errors[0]


@pytest.mark.parametrize(
    "args, needle",
    [
        (["compare", "{kitti}", "--out", "{file}"], "--out: cannot write {file}: it is a file"),
        (["mapclass", "{kitti}", "--out", "{file}"], "--out: cannot write {file}: it is a file"),
        (["batch", "{kitti}", "--out", "{file}"], "--out: cannot write {file}: it is a file"),
        (["classify", "{kitti}", "--labels-out", "{file}"], "--labels-out: cannot write {file}: it is a file"),
        (
            ["classify", "{kitti}", "--labels-out", "{tmp}/lab", "--json", "{file}/m.json"],
            "--json: cannot write {file}/m.json",
        ),
        (
            ["classify", "{kitti}", "--labels-out", "{tmp}/lab", "--las", "{file}/c.las"],
            "--las: cannot write {file}/c.las",
        ),
        (
            ["detect", "{kitti}", "--labels-out", "{tmp}/lab", "--json", "{tmp}"],
            "--json: cannot write {tmp}: it is a directory",
        ),
        (["odometry", "{kitti}", "--poses-out", "{file}/p.txt"], "--poses-out: cannot write {file}/p.txt"),
        (["filter", "{kitti}", "--out", "{file}/x"], "--out: cannot write {file}/x"),
    ],
)
def test_an_output_path_that_cannot_be_written_is_refused_before_any_work(small_kitti, tmp_path, args, needle):
    """It was ``error: [Errno 17] File exists: ...`` (no option named), after the whole run for
    ``--json`` and ``compare --out``: the results were lost."""
    from typer.testing import CliRunner

    from prc_slam.cli import app

    afile = tmp_path / "a file"
    afile.write_text("x")
    fill = {"kitti": str(small_kitti), "file": str(afile), "tmp": str(tmp_path)}
    res = CliRunner().invoke(app, [a.format(**fill) for a in args])
    assert needle.format(**fill) in one_error_line(res)
    assert not (tmp_path / "lab").exists()  # refused before the first frame


@pytest.mark.parametrize("where", ["{tmp}", "{file}/run.log"])
def test_a_log_file_that_cannot_be_written_is_one_line(small_kitti, tmp_path, where):
    """``--log-file`` on a directory, or under a file: a traceback before."""
    from typer.testing import CliRunner

    from prc_slam.cli import app

    afile = tmp_path / "a file"
    afile.write_text("x")
    log_file = where.format(tmp=tmp_path, file=afile)
    res = CliRunner().invoke(app, ["--log-file", log_file, "classify", str(small_kitti)])
    assert f"--log-file: cannot write {log_file}" in one_error_line(res)


def test_existing_output_files_and_folders_are_replaced(small_kitti, tmp_path):
    from typer.testing import CliRunner

    from prc_slam.cli import app

    args = ["classify", str(small_kitti), "--labels-out", str(tmp_path / "lab"), "--json", str(tmp_path / "m.json")]
    args += ["--las", str(tmp_path / "c.las")]
    for _ in range(2):
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
    assert len(list((tmp_path / "lab").iterdir())) == 3 and (tmp_path / "m.json").is_file()
    res = CliRunner().invoke(app, ["compare", str(small_kitti), "--out", str(tmp_path / "lab"), "--variants", "raw"])
    assert res.exit_code == 0, res.output


def test_an_interrupted_classify_says_what_it_left(small_kitti, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from prc_slam.cli import app
    from prc_slam.jobs import sinks

    real = sinks.LabelFiles.frame

    def frame(self, step):
        if step.index == 1:
            raise KeyboardInterrupt
        real(self, step)

    monkeypatch.setattr(sinks.LabelFiles, "frame", frame)
    lab, las = tmp_path / "lab", tmp_path / "c.laz"
    res = CliRunner().invoke(app, ["classify", str(small_kitti), "--labels-out", str(lab), "--las", str(las)])
    assert res.exit_code == 130, res.output
    warning = [line for line in res.output.splitlines() if "interrupted after" in line]
    assert warning and "1 of 3 frames" in warning[0] and str(lab) in warning[0] and str(las) in warning[0]
    assert sorted(p.name for p in lab.iterdir()) == ["000000.label"] and not las.exists()


def test_output_files_are_written_whole_or_not_at_all(tmp_path):
    from data_tools.formats.writers import atomic_path, write_label_file

    path = tmp_path / "000000.label"
    with pytest.raises(KeyboardInterrupt), atomic_path(path) as tmp:
        tmp.write_bytes(b"half a file")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    write_label_file(path, np.array([1, 2, 3], dtype=np.uint8))
    assert np.fromfile(path, np.uint32).tolist() == [1, 2, 3] and len(list(tmp_path.iterdir())) == 1


# --------------------------------------------------------------------------------------------
# ROS recordings

EPOCH_NS = 1_700_000_000 * 10**9


def vlp16_records(layout: list[tuple[str, str, int]], itemsize: int, *, big: bool = False) -> np.ndarray:
    """The real VLP-16 sweep (``multisensor/velodyne_vlp16.pcd``) in a PointCloud2 point layout
    ``(name, numpy type, offset)``: ring from its ``channel``, time (s) from the azimuth."""
    from data_tools.formats.pcd import read_pcd
    from tests.conftest import SHARED_DATA

    path = SHARED_DATA / "multisensor" / "velodyne_vlp16.pcd"
    if not path.is_file():
        pytest.skip(f"real VLP-16 sweep not found: {path}")
    f, _ = read_pcd(path)
    f = {**f, "ring": f["channel"], "time": (np.arctan2(f["y"], f["x"]) % (2 * np.pi)) / (2 * np.pi) * 0.1 - 0.1}
    o = ">" if big else "<"
    dt = np.dtype(
        {
            "names": [n for n, _, _ in layout],
            "formats": [o + t for _, t, _ in layout],
            "offsets": [k for _, _, k in layout],
            "itemsize": itemsize,
        }
    )
    rec = np.zeros(len(f["x"]), dt)
    for name, _, _ in layout:
        rec[name] = f[name]
    return rec


VELODYNE_LAYOUT = [("x", "f4", 0), ("y", "f4", 4), ("z", "f4", 8), ("intensity", "f4", 12), ("ring", "u2", 16)]
VELODYNE_LAYOUT += [("time", "f4", 18)]
XYZ = VELODYNE_LAYOUT[:3]
DRIVER_LAYOUTS = {  # as real drivers publish them: field order, padding, datatypes, byte order
    "reordered_padded": ([(n, t, 40 - 4 * (k + 1)) for k, (n, t, _) in enumerate(VELODYNE_LAYOUT)], 40, False),
    "intensity_ring_uint8": ([*XYZ, ("intensity", "u1", 12), ("ring", "u1", 13), ("time", "f4", 14)], 18, False),
    "intensity_ring_uint16": ([*XYZ, ("intensity", "u2", 12), ("ring", "u2", 14), ("time", "f4", 16)], 20, False),
    "time_float64": ([*VELODYNE_LAYOUT[:5], ("time", "f8", 18)], 26, False),
    "bigendian": (VELODYNE_LAYOUT, 22, True),
}


def prc_labels_of(rec: np.ndarray, **cloud_kw) -> np.ndarray:
    from data_tools.formats.rosbag import cloud_from_records, cloud_to_scan, detect_time_field
    from data_tools.organize import Organizer
    from prc_slam.prc import classify_scan
    from prc_slam.prc.config import PRCConfig

    cloud = cloud_from_records(rec, stamp_ns=EPOCH_NS, **cloud_kw)
    scan = cloud_to_scan(
        cloud, Organizer(sweep_period=0.1), name="000000", source="test", time_field=detect_time_field(cloud, 0.1)
    )
    labels = scan.per_point(classify_scan(scan, PRCConfig.preset("multibeam")))
    assert labels.shape == (len(rec),)
    return labels


@pytest.mark.parametrize("layout", sorted(DRIVER_LAYOUTS))
def test_driver_point_layouts_of_a_real_sweep_give_the_same_labels(layout):
    """These were tried on ROS 1 / ROS 2 / MCAP recordings of the real VLP-16 sweep through
    ``classify``: every one gave the labels of the reference layout (velodyne_pointcloud's)."""
    fields, itemsize, big = DRIVER_LAYOUTS[layout]
    ref = prc_labels_of(vlp16_records(VELODYNE_LAYOUT, 22))
    np.testing.assert_array_equal(prc_labels_of(vlp16_records(fields, itemsize, big=big)), ref)


def test_a_recording_whose_header_stamps_are_unset_is_timed_by_its_log_times(tmp_path, caplog):
    """Every header stamp 0 (a driver that leaves them unset): the frame times were all 0 and the
    odometry stopped at frame 1; the log times time the frames now, and the messages written
    back keep their own stamps."""
    from data_tools.formats.rosbag import RosbagSequence, cloud_from_records
    from data_tools.formats.stream_out import RosCloudWriter

    rec = vlp16_records(VELODYNE_LAYOUT, 22)
    path = tmp_path / "unset stamps.mcap"
    with RosCloudWriter(path, "mcap", "/points") as w:
        for k in range(3):
            w.write_cloud(cloud_from_records(rec, stamp_ns=0), log_time_ns=EPOCH_NS + k * 100_000_000)
    with caplog.at_level(logging.WARNING):
        seq = RosbagSequence(path)
    assert any("header stamps" in r.getMessage() and "log times" in r.getMessage() for r in caplog.records)
    np.testing.assert_allclose(seq.times - 1.7e9, [0.0, 0.1, 0.2], atol=1e-6)
    scans = list(seq)
    for k, scan in enumerate(scans):
        assert scan.meta["frame_time"] == pytest.approx(1.7e9 + 0.1 * k, abs=1e-6)
        assert scan.meta["ros"].stamp == 0.0  # the recorded message, for writers
        t = scan.point_times()
        assert t is not None and abs(np.nanmax(t) - scan.meta["frame_time"]) < 0.01  # the sweep ends at its stamp
    seq.close()


def test_the_summary_counts_points_at_the_origin_as_points_without_a_return(tmp_path):
    """An organised cloud whose no-returns are zeros (Ouster driver): the summary called them
    'non-finite points'."""
    from typer.testing import CliRunner

    from data_tools.formats.rosbag import cloud_from_records
    from data_tools.formats.stream_out import RosCloudWriter
    from prc_slam.cli import app
    from tests.test_unseen_inputs import spinning_grid

    grid = np.nan_to_num(spinning_grid(beams=16, cols=512), nan=0.0)
    rec = np.zeros(grid.shape[:2], [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("ring", "<u2")])
    rec["x"], rec["y"], rec["z"] = grid[..., 0], grid[..., 1], grid[..., 2]
    rec["ring"] = np.arange(16)[:, None]
    path = tmp_path / "zeros.bag"
    with RosCloudWriter(path, "ros1", "/points") as w:
        w.write_cloud(cloud_from_records(rec.ravel(), height=16, stamp_ns=EPOCH_NS))
    res = CliRunner().invoke(app, ["classify", str(path)])
    assert res.exit_code == 0, res.output
    zeros = int((grid == 0).all(axis=-1).sum())
    assert f"{zeros} points without a return" in res.output and "non-finite" not in res.output


def velodyne_scan_bag(path: Path, kind: str, payloads: list[bytes], stamps: list[float], topic: str) -> Path:
    """A recording of raw packets as ``rosbag record /velodyne_packets`` stores them: one
    ``velodyne_msgs/VelodyneScan`` per 75 packets, each packet with its stamp."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = get_types_from_msg("builtin_interfaces/Time stamp\nuint8[1206] data\n", "velodyne_msgs/msg/VelodynePacket")
    header = "std_msgs/Header header\nVelodynePacket[] packets\n"
    types.update(get_types_from_msg(header, "velodyne_msgs/msg/VelodyneScan"))
    ts.register(types)
    T = ts.types

    def stamp(t: float):
        sec = int(t)
        return T["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((t - sec) * 1e9))

    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer, serialize = Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3), ts.serialize_cdr
    with writer as w:
        conn = w.add_connection(topic, "velodyne_msgs/msg/VelodyneScan", typestore=ts)
        for k in range(0, len(payloads), 75):
            packets = [
                T["velodyne_msgs/msg/VelodynePacket"](stamp=stamp(t), data=np.frombuffer(p, np.uint8))
                for p, t in zip(payloads[k : k + 75], stamps[k : k + 75], strict=True)
            ]
            extra = {"seq": k} if kind == "ros1" else {}
            hdr = T["std_msgs/msg/Header"](stamp=stamp(stamps[k]), frame_id="velodyne", **extra)
            msg = T["velodyne_msgs/msg/VelodyneScan"](header=hdr, packets=packets)
            w.write(conn, round(stamps[k] * 1e9), serialize(msg, "velodyne_msgs/msg/VelodyneScan"))
    return path


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_a_recording_of_raw_velodyne_packets_is_decoded_like_the_capture(kind, vlp16_frames, reference, tmp_path):
    """A bag recorded from ``/velodyne_packets`` (velodyne_msgs/VelodyneScan, common in public
    datasets) was refused ('no PointCloud2 topic'): its packets are decoded as a capture's."""
    payloads, stamps, _ = vlp16_stream(n_sweeps=2.3)
    name = "packets.bag" if kind == "ros1" else "packets"
    path = velodyne_scan_bag(tmp_path / name, kind, payloads, stamps, "/velodyne_packets")
    ds = open_dataset(path)
    assert ds.model == "VLP16" and ds.topic == "/velodyne_packets"
    same_sweeps(ds, reference)
    scan = ds[0]
    assert scan.meta["organize"]["rings"] == 16 and scan.n_points == len(reference[1][0])


def test_two_velodyne_packet_topics_need_a_topic(tmp_path):
    pytest.importorskip("velodyne_decoder", reason="velodyne-decoder is not installed")
    payloads, stamps, _ = vlp16_stream(n_sweeps=0.3)
    path = velodyne_scan_bag(tmp_path / "a.bag", "ros1", payloads, stamps, "/front/velodyne_packets")
    both = tmp_path / "both"  # a folder of split bags, one topic each
    both.mkdir()
    velodyne_scan_bag(both / "1.bag", "ros1", payloads, stamps, "/front/velodyne_packets")
    velodyne_scan_bag(both / "2.bag", "ros1", payloads, stamps, "/rear/velodyne_packets")
    with pytest.raises(DataError, match="2 VelodyneScan topics, choose one with --topic") as exc:
        open_dataset(both)
    assert "/front/velodyne_packets" in str(exc.value) and "/rear/velodyne_packets" in str(exc.value)
    assert len(open_dataset(both, topic="/rear/velodyne_packets")) >= 1
    assert open_dataset(path).topic == "/front/velodyne_packets"
