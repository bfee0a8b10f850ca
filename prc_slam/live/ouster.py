"""Ouster lidar packets on the wire → whole sweeps, decoded with ``ouster-sdk`` from the sensor's
metadata json (``--meta``).

ouster-sdk 1.0's own live source (``SensorPacketSource`` over a ``Sensor``) talks to the sensor's
HTTP API unless it is given the metadata; given it, it opens the ports without the API, but it
delivered no packet of a loopback replay of the shared captures before its timeout
(``ClientTimeout``), and it listens on the sensor's configured ports only. So the packets are
received here (one UDP socket, any port, as for Velodyne) and decoded with the SDK's
``PacketFormat`` and ``FrameBatcher`` from the metadata, exactly as the offline reader
(:class:`data_tools.formats.ouster_pcap.OusterPcapSequence`) decodes a capture: a sweep is a run of lidar
packets of one frame id (a new frame id, or the measurement ids starting again, closes it),
batched into a fresh ``LidarFrame``, and turned into a Scan by the offline reader's own code.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from data_tools.errors import DataError
from data_tools.formats.ouster_pcap import OusterPcapSequence

log = logging.getLogger("prc_slam")


class LiveOusterFrames(OusterPcapSequence):
    """:class:`~data_tools.formats.ouster_pcap.OusterPcapSequence` over frames batched from received
    packets (``lidar_frames``, ``frame_ids`` by sweep index) instead of a capture's."""

    lidar_frames: dict[int, Any]

    def __len__(self) -> int:
        return 2**62

    def frame(self, i: int):
        return self.lidar_frames[i]


class OusterAssembler:
    """Lidar packets of one Ouster (its metadata json) → sweeps, as the offline reader cuts them.

    Parameters
    ----------
    name : the source, for messages
    meta : the sensor's metadata json
    """

    def __init__(self, name: str, meta: Path | None, destaggered: bool = True) -> None:
        from data_tools.formats.ouster_pcap import load_sensor_info

        if meta is None:
            raise DataError(f"{name}: ouster:// needs the sensor's metadata json (--meta)")
        meta = Path(meta)
        if not meta.is_file():
            raise DataError(f"--meta {meta}: no such file")
        from ouster.sdk import core

        info = load_sensor_info(meta, meta)
        reader = LiveOusterFrames.__new__(LiveOusterFrames)
        reader.root = Path(name)
        reader.name = name
        reader.destaggered = destaggered
        reader.field = "RANGE"
        reader.info = info
        reader.meta_path = meta
        reader._core = core
        reader._format = core.PacketFormat(info)
        reader.poses = None
        reader._lut = core.XYZLut(info, use_extrinsics=False)
        t = np.linalg.inv(np.asarray(info.lidar_to_sensor_transform, dtype=np.float64))
        reader._to_lidar = (t[:3, :3], t[:3, 3] / 1000.0)
        reader.frame_ids = {}
        reader.lidar_frames = {}
        self.reader = reader
        self.core = core
        self.format = reader._format
        self.size = int(self.format.lidar_packet_size)
        self.per_frame = -(-int(info.format.columns_per_frame) // int(self.format.columns_per_packet))
        window = reader._in_window()
        self.expected = -(-int(window.sum()) // int(self.format.columns_per_packet))
        self.index = 0
        self._packets: list[Any] = []
        self._fid: int | None = None
        self._last_mid = -1

    def accept(self, payload: bytes) -> bool:
        """A lidar packet of this metadata's profile (its size)."""
        return len(payload) == self.size

    def _packet(self, payload: bytes):
        p = self.core.LidarPacket(self.format)
        p.buf[:] = np.frombuffer(payload, dtype=np.uint8)
        return p

    def feed(self, payload: bytes, now_wall: float) -> tuple[float, Any, int] | None:
        """One lidar packet; the sweep it closes as (stamp, LidarFrame, lost packets), else None."""
        p = self._packet(payload)
        fid = int(p.frame_id())
        mids = np.asarray(self.format.packet_header(self.core.ColHeader.MEASUREMENT_ID, p.buf))
        first_mid = int(mids.min()) if len(mids) else 0
        done = None
        if self._packets and (fid != self._fid or first_mid <= self._last_mid):
            done = self._close()
        self._packets.append(p)
        self._fid, self._last_mid = fid, int(mids.max()) if len(mids) else first_mid
        return done

    def _close(self) -> tuple[float, Any, int] | None:
        packets, self._packets = self._packets, []
        lf = self.core.LidarFrame(self.reader.info)
        batcher = self.core.FrameBatcher(self.reader.info)
        for p in packets:
            batcher.batch(p, lf)
        lost = max(0, self.expected - len(packets))
        ts = np.asarray(lf.timestamp)
        ok = ts > 0
        stamp = float(ts[ok].min()) * 1e-9 if ok.any() else 0.0
        return stamp, (lf, self._fid), lost

    def finish(self) -> tuple[float, Any, int] | None:
        """The sweep being assembled, as it is (the end of the stream)."""
        return self._close() if self._packets else None

    def scan_of(self, sweep) -> Any:
        """The Scan of a received sweep: the offline reader's own construction."""
        lf, fid = sweep.points
        i = sweep.index
        self.reader.frame_ids[i] = fid
        self.reader.lidar_frames[i] = lf
        try:
            return self.reader[i]
        finally:
            self.reader.lidar_frames.pop(i, None)
            self.reader.frame_ids.pop(i, None)
