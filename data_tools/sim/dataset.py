"""The simulator's dataset directory, its reader, and the KITTI/SemanticKITTI export.

Layout of a simulated sequence::

    sim.json            format, the SimConfig used, sensor model, scene summary
    config.yaml         the SimConfig used
    frames/NNNNNN.npz   ranges, intensity, labels, instance, noise_kind, slot_times,
                        line_times, line_poses (per column or per scan line), pose
    poses.txt           KITTI format, sensor pose at each frame's reference (mid) time
    times.txt           reference times (s)
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

from data_tools.errors import DataError
from data_tools.formats.kitti import read_kitti_poses, read_times
from data_tools.formats.npz import save_npz
from data_tools.formats.trajectory_io import write_kitti_poses
from data_tools.sequence import SequenceBase
from data_tools.sim.simulator import NOISE_KINDS, SimConfig, SimFrame, Simulator
from prc_slam import labels as L
from prc_slam.scan import Scan, sensor_from_description

FORMAT = "prc-slam-sim"
FRAME_KEYS = (
    "ranges",
    "intensity",
    "labels",
    "instance",
    "noise_kind",
    "slot_times",
    "line_times",
    "line_poses",
    "pose",
)


def write_sequence(sim: Simulator, out: str | Path, on_frame: Callable[[SimFrame], None] | None = None) -> Path:
    """Render every frame of ``sim`` into the dataset directory ``out``."""
    out = Path(out)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    cfg = sim.config
    sensor = sim.sensor
    meta = {
        "format": FORMAT,
        "version": 1,
        "config": cfg.model_dump(mode="json"),
        "sensor": {
            "name": sensor.name,
            "model": sensor.model.describe(),
            "period": sensor.period,
            "range_sigma": sensor.range_sigma,
            "min_range": sensor.min_range,
            "max_range": sensor.max_range,
            "mixed_pixel_rate": sensor.mixed_pixel_rate,
            "platform": sensor.platform,
        },
        "scene": {
            "kind": sim.scene.kind,
            "seed": sim.scene.seed,
            "triangles": sim.scene.mesh.n_triangles,
            **{k: v for k, v in sim.scene.info.items() if isinstance(v, int | float | str)},
        },
        "noise_kinds": list(NOISE_KINDS),
        "frame_pose_time": "mid",
        "labels": {str(i.code): i.name for i in L.LABELS},
    }
    (out / "sim.json").write_text(json.dumps(meta, indent=2) + "\n")
    (out / "config.yaml").write_text(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))
    poses, times = [], []
    for i in range(cfg.frames):
        f = sim.frame(i)
        save_npz(out / "frames" / f"{i:06d}.npz", **{k: getattr(f, k) for k in FRAME_KEYS})
        poses.append(f.pose)
        times.append(f.time)
        if on_frame is not None:
            on_frame(f)
    write_kitti_poses(out / "poses.txt", np.array(poses))
    np.savetxt(out / "times.txt", np.array(times), fmt="%.6f")
    return out


class SimSequence(SequenceBase):
    """Reader of a simulated sequence directory (``sim.json`` + ``frames/``)."""

    format = "sim"

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        meta_path = self.root / "sim.json"
        try:
            self.meta = json.loads(meta_path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise DataError(f"{meta_path}: cannot read simulator metadata: {exc}") from exc
        if self.meta.get("format") != FORMAT:
            raise DataError(f"{meta_path}: not a {FORMAT} directory")
        self.files = sorted((self.root / "frames").glob("*.npz"))
        if not self.files:
            raise DataError(f"{self.root / 'frames'}: no frames")
        self.sensor = sensor_from_description(self.meta["sensor"]["model"])
        self.config = SimConfig.model_validate(self.meta["config"])
        self.name = self.root.name
        self.poses = read_kitti_poses(self.root / "poses.txt")
        self.times = read_times(self.root / "times.txt")
        if len(self.poses) != len(self.files) or len(self.times) != len(self.files):
            raise DataError(
                f"{self.root}: {len(self.files)} frames but {len(self.poses)} poses, {len(self.times)} times"
            )

    def __getitem__(self, i: int) -> Scan:
        path = self.files[i]
        try:
            with np.load(path) as z:
                data = {k: z[k] for k in FRAME_KEYS}
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            raise DataError(f"{path}: cannot read simulated frame: {exc}") from exc
        return Scan(
            ranges=data["ranges"],
            sensor=self.sensor,
            name=path.stem,
            source=str(path),
            intensity=data["intensity"],
            timestamps=data["slot_times"],
            gt_labels=data["labels"],
            gt_instance=data["instance"],
            gt_pose=self.poses[i],
            meta={
                "noise_kind": data["noise_kind"],
                "line_times": data["line_times"],
                "line_poses": data["line_poses"],
                "frame_time": float(self.times[i]),
            },
        )


KITTI_CALIB = "".join(f"P{i}: 1 0 0 0 0 1 0 0 0 0 1 0\n" for i in range(4)) + "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n"


def export_kitti(seq: SimSequence, out: str | Path, on_frame: Callable[[int], None] | None = None) -> Path:
    """Write a KITTI/SemanticKITTI directory: ``velodyne/*.bin`` (x, y, z, intensity in [0, 1],
    raw points in the sensor frame at their firing time, ring by ring), ``labels/*.label``,
    ``poses.txt`` (LiDAR poses; ``calib.txt``'s ``Tr`` is the identity), ``times.txt``."""
    if seq.sensor.continuous_rows:
        raise DataError(f"{seq.root}: KITTI export needs a spinning sensor, this sequence is a profiler")
    out = Path(out)
    (out / "velodyne").mkdir(parents=True, exist_ok=True)
    (out / "labels").mkdir(parents=True, exist_ok=True)
    for i in range(len(seq)):
        scan = seq[i]
        valid = scan.valid
        xyz = scan.slot_xyz()[valid]
        pts = np.column_stack([xyz, scan.intensity[valid] / 255.0]).astype(np.float32)
        pts.tofile(out / "velodyne" / f"{scan.name}.bin")
        L.to_semantic_kitti(scan.gt_labels[valid], scan.gt_instance[valid]).tofile(
            out / "labels" / f"{scan.name}.label"
        )
        if on_frame is not None:
            on_frame(i)
    write_kitti_poses(out / "poses.txt", seq.poses)
    np.savetxt(out / "times.txt", seq.times, fmt="%.6e")
    (out / "calib.txt").write_text(KITTI_CALIB)
    # the KITTI odometry benchmark layout as well (relative links), for tools that expect it,
    # e.g. ``kiss_icp_pipeline --dataloader kitti --sequence 00 OUT``
    seq_dir = out / "sequences" / "00"
    seq_dir.mkdir(parents=True, exist_ok=True)
    (out / "poses").mkdir(exist_ok=True)
    links = [(seq_dir / n, Path("../..") / n) for n in ("velodyne", "labels", "calib.txt", "times.txt")]
    links.append((out / "poses" / "00.txt", Path("../poses.txt")))
    for link, target in links:
        if not link.is_symlink():
            link.symlink_to(target)
    return out
