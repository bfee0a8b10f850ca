"""Simulated sweeps written as Velodyne VLP-16 / HDL-32E packets decode back to the same points."""

from __future__ import annotations

import numpy as np
import pytest

from data_tools.errors import DataError
from data_tools.formats.velodyne_packets import FORMATS, PACKET_SIZE, PacketEncoder, lasers_of_rows


@pytest.fixture(scope="module")
def vlp16_sim(tmp_path_factory):
    """Three simulated VLP-16 sweeps (clockwise) and their capture."""
    from data_tools.formats.velodyne_packets import SimCapture
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    root = tmp_path_factory.mktemp("vlp16")
    sim = Simulator(SimConfig(sensor="vlp16", frames=3, clockwise=True))
    cap = SimCapture(root / "cap.pcap", sim.sensor, "vlp16")
    frames = []

    def keep(frame):
        cap.add(frame)
        frames.append(frame)

    write_sequence(sim, root / "seq", on_frame=keep)
    cap.close()
    return root / "cap.pcap", frames, sim.sensor


def test_packets_have_the_format(vlp16_sim):
    from data_tools.formats.velodyne_pcap import Capture

    path, _frames, _sensor = vlp16_sim
    packets = list(Capture(path))
    assert len(packets) == 3 * 1800 // 24  # 24 firings per VLP-16 packet
    for _t, src, payload in packets[:5]:
        assert len(payload) == PACKET_SIZE
        assert src.endswith("port 2368")
        assert payload[-2:] == b"\x37\x22"  # strongest return, VLP-16
        assert all(payload[100 * b : 100 * b + 2] == b"\xff\xee" for b in range(12))


def test_packets_hold_the_simulated_ranges(vlp16_sim):
    """The packets' distances are the simulated ranges in 2 mm units, laser by laser, firing by firing."""
    from data_tools.formats.velodyne_packets import PACKET_DTYPE, laser_elevations
    from data_tools.formats.velodyne_pcap import Capture

    path, frames, sensor = vlp16_sim
    raw = b"".join(p for _t, _s, p in Capture(path))
    pk = np.frombuffer(raw, dtype=PACKET_DTYPE)
    dist = pk["blocks"]["channels"]["distance"].reshape(-1, 16)  # one firing per row, laser ids across
    ranges = np.concatenate([f.ranges for f in frames], axis=1)  # rows x firings
    ids = lasers_of_rows(sensor.model.altitude, FORMATS["vlp16"])
    assert np.allclose(np.degrees(laser_elevations(FORMATS["vlp16"])[ids]), np.degrees(sensor.model.altitude))
    units = np.round(ranges.astype(np.float64) / 0.002).astype(np.int64)
    units[ranges <= 0] = 0
    assert np.array_equal(dist[:, ids].T.astype(np.int64), units)


def test_decoded_sweeps_are_the_simulated_ones(vlp16_sim):
    """Every return comes back on its ring, in firing order, at its range and its beam's elevation
    (the decoder cuts sweeps where it likes: the stream is compared whole). The tolerance is the
    decoder's own: a constant 10 m in the packets decodes to 9.997-10.000 m (VLP-16)."""
    from data_tools.formats.velodyne_pcap import VelodynePcapSequence

    path, frames, sensor = vlp16_sim
    seq = VelodynePcapSequence(path)
    assert seq.model == "VLP16" and len(seq) >= 3
    rows = sensor.model.rows
    pts = np.concatenate([seq.sweep(i)[1] for i in range(len(seq))])
    d = np.sqrt(pts["x"].astype(float) ** 2 + pts["y"] ** 2 + pts["z"] ** 2)
    for ring in range(rows):
        sim_rows = np.concatenate([f.ranges[rows - 1 - ring] for f in frames])  # ring 0 is the lowest beam
        want = sim_rows[sim_rows > 0]
        got = d[pts["ring"] == ring]
        assert len(got) == len(want)
        assert np.abs(got - want).max() <= 0.005
        elev = np.degrees(np.arcsin(pts["z"][pts["ring"] == ring] / got))
        # within a quarter of the 2 deg beam spacing (the decoder's geometry moves near points by ~1 cm)
        assert np.abs(elev - np.degrees(sensor.model.altitude[rows - 1 - ring])).max() < 0.5


def test_encoder_needs_a_clockwise_sensor_of_the_model():
    alt = np.radians(np.linspace(15, -15, 16))
    ccw = 2 * np.pi * (np.arange(1800) + 0.5) / 1800
    with pytest.raises(DataError, match="clockwise"):
        PacketEncoder(FORMATS["vlp16"], alt, ccw)
    with pytest.raises(DataError, match="32 beams"):
        lasers_of_rows(alt, FORMATS["hdl32"])


def test_simulate_pcap_option_names_unsupported_sensors(tmp_path):
    from typer.testing import CliRunner

    from prc_slam.cli import app

    res = CliRunner().invoke(app, ["simulate", "--out", str(tmp_path / "s"), "--sensor", "os1-64", "--pcap", "x.pcap"])
    assert res.exit_code == 2
    assert "--pcap" in res.output and "os1-64" in res.output


def test_simulate_writes_the_capture_beside_the_sequence(tmp_path):
    import json

    from typer.testing import CliRunner

    from data_tools.formats.velodyne_pcap import VelodynePcapSequence
    from prc_slam.cli import app

    res = CliRunner().invoke(
        app,
        [
            "simulate",
            "--out",
            str(tmp_path / "s"),
            "--sensor",
            "vlp16",
            "--frames",
            "2",
            "--pcap",
            str(tmp_path / "c.pcap"),
        ],
    )
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "s" / "sim.json").read_text())["config"]["clockwise"] is True
    seq = VelodynePcapSequence(tmp_path / "c.pcap")
    assert seq.model == "VLP16" and sum(len(seq.sweep(i)[1]) for i in range(len(seq))) > 10_000
