"""Record what every reader and the organiser make of a fixed set of inputs, and compare two records.

``record OUT_DIR`` opens every input below with :func:`data_tools.open_dataset` (format detected) and
writes ``OUT_DIR/snapshot.json``: per input the detected format, the dataset's class, length,
poses and times, and per frame the sha256 (with dtype and shape) of every array of the organised
Scan (ranges, intensity, timestamps, xyz, cloud, slot map, ground truth), its sensor model, the
organiser's report and the PRC labels (:func:`prc_slam.prc.classify_scan` with the default
configuration, per slot and per input point). It also records the error message of a set of
inputs that must be refused, and the bytes of the recordings it writes itself (PCD, PLY, bin,
LAS, ROS 1 bag, MCAP, Velodyne pcap), so that a change to a writer shows too.

Inputs: the shared real data (``../shared/data``: KITTI 00's sweeps with their labels, the Ouster
pcaps and decoded ``.npz``, the multisensor PCDs) when present, and small recordings of a simulated
drive written into ``OUT_DIR/inputs``: PCD folders (binary with ring and time fields,
binary_compressed, ascii, without ring), a PLY sweep, a KITTI bin folder, a LAS sweep, an MCAP and a
ROS 1 bag in three driver layouts, and a Velodyne pcap (``prc-slam simulate --pcap``).

With ``--full`` it also records the online detectors' labels of every frame
(:class:`prc_slam.online.OnlineDetector`, one per input, frames in order) and ``prc-slam compare``'s
metrics without the timings (and its trajectory files) on a simulated 12-sweep HDL-64E drive.

``compare A B`` prints every entry that differs between two records and exits 1 when any does,
0 (``identical``) otherwise.

Usage::

    .venv/bin/python scripts/behaviour_snapshot.py record /tmp/snap/before
    .venv/bin/python scripts/behaviour_snapshot.py compare /tmp/snap/before /tmp/snap/after
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
#: meta entries that hold timings (differ from run to run)
TIMING_META = ("organize_seconds", "organize_span")
#: metrics keys that hold timings or memory (left out of ``--full``'s compare metrics)
TIMING_KEYS = re.compile(r"(^ms$|^ms_|_ms$|seconds|per_s$|rss|wall|elapsed|speed|_hz$)")


def digest(a: Any) -> str | None:
    """``dtype shape sha256`` of an array (None for None)."""
    if a is None:
        return None
    a = np.ascontiguousarray(a)
    return f"{a.dtype.str} {list(a.shape)} {hashlib.sha256(a.tobytes()).hexdigest()[:32]}"


def plain(v: Any) -> Any:
    """A JSON-able form of ``v`` (arrays as digests)."""
    if isinstance(v, np.ndarray):
        return digest(v)
    if isinstance(v, dict):
        return {str(k): plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [plain(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    if v is None or isinstance(v, bool | int | float | str):
        return v
    return repr(v)


def scan_record(scan: Any, online: Any = None) -> dict[str, Any]:
    """Digests of an organised Scan and of its PRC labels (and of ``online``'s labels: an
    :class:`~prc_slam.online.OnlineDetector` of the sequence)."""
    from prc_slam.prc import PRCConfig, classify_scan

    rec: dict[str, Any] = {"name": scan.name, "source": Path(scan.source).name, "shape": list(scan.shape)}
    for key in ("ranges", "intensity", "timestamps", "xyz", "cloud", "point_slot", "gt_labels"):
        rec[key] = digest(getattr(scan, key))
    for key in ("gt_point_labels", "gt_instance", "gt_pose"):
        rec[key] = digest(getattr(scan, key))
    sensor = scan.sensor
    rec["sensor"] = {"class": type(sensor).__name__}
    if dataclasses.is_dataclass(sensor):
        rec["sensor"].update({f.name: plain(getattr(sensor, f.name)) for f in dataclasses.fields(sensor)})
    rec["meta"] = plain({k: v for k, v in scan.meta.items() if k not in TIMING_META})
    labels = classify_scan(scan, PRCConfig())
    rec["prc_labels"] = digest(labels)
    rec["prc_point_labels"] = digest(scan.per_point(labels)) if scan.point_slot is not None else None
    if online is not None:
        try:
            rec["online_labels"] = digest(online.process(scan).labels)
        except Exception as exc:
            rec["online_labels"] = f"{type(exc).__name__}: {exc}"
    return rec


#: record the online detectors' labels too (``--full``)
FULL = {"online": False}


def dataset_record(path: Path, frames: int | None = None, **options: Any) -> dict[str, Any]:
    """The detected format and every frame's record (or the error) of one input."""
    from data_tools import open_dataset
    from data_tools.datasets import detect_format
    from data_tools.errors import DataError

    rec: dict[str, Any] = {}
    try:
        rec["format"] = detect_format(path)
        ds = open_dataset(path, **options)
        rec["class"] = type(ds).__name__
        rec["len"] = len(ds)
        rec["poses"] = digest(getattr(ds, "poses", None))
        rec["times"] = digest(getattr(ds, "times", None))
        n = len(ds) if frames is None else min(frames, len(ds))
        online = None
        if FULL["online"]:
            from prc_slam.online import OnlineDetector

            online = OnlineDetector()
        rec["frames"] = [scan_record(ds[i], online) for i in range(n)]
        if n > 1:  # iteration gives the same scans as indexing
            rec["iter_ranges"] = [digest(s.ranges) for _, s in zip(range(n), iter(ds), strict=False)]
    except DataError as exc:
        rec["error"] = str(exc).replace(str(path), "<path>")
    return rec


# ----------------------------------------------------------------------------- generated inputs


def _sim(sensor: str, frames: int) -> tuple[Any, list[Any]]:
    from data_tools.sim.simulator import SimConfig, Simulator

    sim = Simulator(SimConfig(sensor=sensor, frames=frames, seed=2))
    return sim.sensor.model, [sim.frame(i) for i in range(frames)]


def _points(model: Any, frame: Any) -> tuple[np.ndarray, np.ndarray]:
    """The returns of a simulated sweep in ring-major order and their slots."""
    slots = np.flatnonzero(frame.ranges.reshape(-1) > 0)
    return model.to_xyz(frame.ranges).reshape(-1, 3)[slots], slots


def _write_ascii_pcd(path: Path, fields: dict[str, np.ndarray]) -> None:
    names = list(fields)
    types = ["F" if fields[k].dtype.kind == "f" else ("U" if fields[k].dtype.kind == "u" else "I") for k in names]
    header = (
        f"VERSION 0.7\nFIELDS {' '.join(names)}\nSIZE {' '.join(str(fields[k].dtype.itemsize) for k in names)}\n"
        f"TYPE {' '.join(types)}\nCOUNT {' '.join('1' for _ in names)}\nWIDTH {len(fields[names[0]])}\nHEIGHT 1\n"
        f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(fields[names[0]])}\nDATA ascii\n"
    )
    cols = [np.char.mod("%.9g" if fields[k].dtype.kind == "f" else "%d", fields[k]) for k in names]
    body = "\n".join(" ".join(row) for row in zip(*cols, strict=True))
    path.write_text(header + body + "\n")


def _write_compressed_pcd(path: Path, fields: dict[str, np.ndarray]) -> None:
    names = list(fields)
    types = ["F" if fields[k].dtype.kind == "f" else ("U" if fields[k].dtype.kind == "u" else "I") for k in names]
    n = len(fields[names[0]])
    raw = b"".join(np.ascontiguousarray(fields[k]).tobytes() for k in names)
    comp = b"".join(bytes([len(raw[i : i + 32]) - 1]) + raw[i : i + 32] for i in range(0, len(raw), 32))  # LZF literals
    header = (
        f"VERSION 0.7\nFIELDS {' '.join(names)}\nSIZE {' '.join(str(fields[k].dtype.itemsize) for k in names)}\n"
        f"TYPE {' '.join(types)}\nCOUNT {' '.join('1' for _ in names)}\nWIDTH {n}\nHEIGHT 1\n"
        f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary_compressed\n"
    )
    path.write_bytes(header.encode() + np.array([len(comp), len(raw)], "<u4").tobytes() + comp)


def generate_inputs(root: Path) -> dict[str, Path]:
    """Write the small recordings of simulated drives; returns name -> path."""
    from data_tools.formats.pcd import write_pcd
    from data_tools.formats.rosbag import cloud_from_records
    from data_tools.formats.stream_out import RosCloudWriter
    from data_tools.formats.writers import write_las, write_ply

    root.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    vlp, vframes = _sim("vlp16", 3)
    hdl, hframes = _sim("hdl64", 2)
    names = ("pcd_ring", "pcd_plain", "pcd_compressed", "pcd_ascii", "kitti_bin", "organised", "tilted")
    dirs = {k: root / k for k in names}
    for d in dirs.values():
        d.mkdir(exist_ok=True)
    rng = np.random.default_rng(0)
    for f in vframes:
        xyz, slots = _points(vlp, f)
        ring = (vlp.rows - 1 - slots // vlp.cols).astype(np.uint16)
        t = (f.slot_times.reshape(-1)[slots] - f.slot_times.min()).astype(np.float32)
        inten = f.intensity.reshape(-1)[slots].astype(np.float32)
        label = rng.integers(0, 20, len(slots)).astype(np.uint32)
        fields = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": inten, "ring": ring, "time": t}
        write_pcd(dirs["pcd_ring"] / f"{f.index:06d}.pcd", {**fields, "label": label})
        _write_compressed_pcd(dirs["pcd_compressed"] / f"{f.index:06d}.pcd", {**fields, "label": label})
        _write_ascii_pcd(dirs["pcd_ascii"] / f"{f.index:06d}.pcd", {**fields, "label": label})
    for f in hframes:
        xyz, slots = _points(hdl, f)
        inten = f.intensity.reshape(-1)[slots].astype(np.float32)
        write_pcd(dirs["pcd_plain"] / f"{f.index:06d}.pcd", {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]})
        np.column_stack([xyz, inten]).astype(np.float32).tofile(dirs["kitti_bin"] / f"{f.index:06d}.bin")
        c, s = np.cos(np.radians(4.0)), np.sin(np.radians(4.0))
        tilted = xyz @ np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]).T  # a sweep in a tilted frame
        write_pcd(dirs["tilted"] / f"{f.index:06d}.pcd", {"x": tilted[:, 0], "y": tilted[:, 1], "z": tilted[:, 2]})
        grid = hdl.to_xyz(f.ranges).astype(np.float32)
        write_pcd(
            dirs["organised"] / f"{f.index:06d}.pcd",
            {"x": grid[..., 0].ravel(), "y": grid[..., 1].ravel(), "z": grid[..., 2].ravel()},
            height=hdl.rows,
        )
    out.update({k: v for k, v in dirs.items()})
    f = hframes[0]
    xyz, slots = _points(hdl, f)
    write_ply(root / "sweep.ply", xyz)
    out["ply"] = root / "sweep.ply"
    write_las(root / "sweep.las", xyz, np.ones(len(xyz), np.uint8))
    out["las"] = root / "sweep.las"
    # recordings: velodyne (ring, time), ouster (organised), no ring (absolute double timestamps)
    velodyne = np.dtype(
        {
            "names": ["x", "y", "z", "intensity", "ring", "time"],
            "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
            "offsets": [0, 4, 8, 12, 16, 18],
            "itemsize": 22,
        }
    )
    no_ring = np.dtype({"names": ["x", "y", "z", "intensity", "timestamp"], "formats": ["<f4"] * 4 + ["<f8"]})
    epoch = 1_700_000_000
    clouds: dict[str, list[Any]] = {"velodyne": [], "organised": [], "no_ring": []}
    for f in vframes:
        xyz, slots = _points(vlp, f)
        rec = np.zeros(len(slots), velodyne)
        rec["x"], rec["y"], rec["z"] = xyz.T
        rec["intensity"] = f.intensity.reshape(-1)[slots]
        rec["ring"] = vlp.rows - 1 - slots // vlp.cols
        stamp = epoch + float(f.slot_times.max())
        rec["time"] = (epoch + f.slot_times.reshape(-1)[slots]) - stamp
        clouds["velodyne"].append(cloud_from_records(rec, frame_id="velodyne", stamp_ns=round(stamp * 1e9)))
    for f in hframes:
        grid = hdl.to_xyz(f.ranges).reshape(-1, 3)
        org = np.zeros(len(grid), np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("t", "<u4")]))
        org["x"], org["y"], org["z"] = grid.T
        org["t"] = np.round((f.slot_times.reshape(-1) - f.slot_times.min()) * 1e9).astype(np.uint32)
        stamp = epoch + float(f.slot_times.min())
        clouds["organised"].append(cloud_from_records(org, height=hdl.rows, stamp_ns=round(stamp * 1e9)))
        xyz, slots = _points(hdl, f)
        order = np.argsort(slots % hdl.cols, kind="stable")  # column-major (firing order)
        rec = np.zeros(len(slots), no_ring)
        rec["x"], rec["y"], rec["z"] = xyz[order].T
        rec["timestamp"] = epoch + f.slot_times.reshape(-1)[slots][order]
        clouds["no_ring"].append(cloud_from_records(rec, stamp_ns=round(stamp * 1e9)))
    for name, cl in clouds.items():
        for kind, suffix in (("mcap", ".mcap"), ("ros1", ".bag")):
            path = root / f"{name}{suffix}"
            with RosCloudWriter(path, kind, "/points") as w:
                for c in cl:
                    w.write_cloud(c)
            out[f"{name}_{kind}"] = path
    pcap_dir = root / "sim_pcap"
    cmd = [
        str(Path(sys.executable).parent / "prc-slam"), "simulate", "--out", str(pcap_dir), "--sensor", "vlp16",
        "--frames", "3", "--seed", "2", "--pcap", str(root / "vlp16.pcap"),
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode == 0 and (root / "vlp16.pcap").is_file():
        out["velodyne_pcap"] = root / "vlp16.pcap"
        out["sim"] = pcap_dir
    else:
        print(f"prc-slam simulate --pcap failed ({done.returncode}): {done.stderr.strip()[-300:]}", file=sys.stderr)
    return out


def bad_inputs(root: Path) -> dict[str, Path]:
    """Inputs that must be refused, each with its one-line message."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "empty_dir").mkdir(exist_ok=True)
    (root / "notes.txt").write_text("hello\n")
    (root / "empty.pcap").write_bytes(b"")
    (root / "foreign.pcap").write_bytes(b"\x00" * 64)
    (root / "bad.pcd").write_text("not a pcd\n")
    (root / "trunc.bin").write_bytes(b"\x00" * 10)
    (root / "short.npz").write_bytes(b"PK\x03\x04")
    (root / "bad.bag").write_bytes(b"#ROSBAG V2.0\n")
    (root / "bad.mcap").write_bytes(b"\x89MCAP0\r\n")
    (root / "bad.ply").write_text("ply\nformat ascii 1.0\n")
    (root / "bad.las").write_bytes(b"LASF")
    return {p.name: p for p in sorted(root.iterdir())} | {"missing": root / "missing"}


# ----------------------------------------------------------------------------- record / compare


def file_digest(path: Path) -> dict[str, str]:
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    skip = ("config.yaml", "sim.json", "metadata.yaml")  # hold versions or paths
    return {
        str(p.relative_to(path) if path.is_dir() else p.name): hashlib.sha256(p.read_bytes()).hexdigest()[:32]
        for p in files
        if p.name not in skip
    }


def untimed(v: Any) -> Any:
    """``v`` without the entries whose keys name timings (:data:`TIMING_KEYS`), floats to 9
    significant digits (KISS-ICP's threaded sums differ from run to run in the last bits)."""
    if isinstance(v, dict):
        return {k: untimed(x) for k, x in v.items() if not TIMING_KEYS.search(str(k))}
    if isinstance(v, list):
        return [untimed(x) for x in v]
    if isinstance(v, float):
        return float(f"{v:.9g}")
    return v


def compare_record(root: Path) -> dict[str, Any]:
    """``prc-slam compare`` (raw, prc) on a simulated 12-sweep HDL-64E drive: its metrics without
    timings (:func:`untimed`) and its trajectory files' poses to 9 significant digits."""
    cli = str(Path(sys.executable).parent / "prc-slam")
    drive, res = root / "drive", root / "compare"
    steps = (
        [cli, "simulate", "--out", str(drive), "--sensor", "hdl64", "--frames", "12", "--seed", "3"],
        [cli, "compare", str(drive), "--variants", "raw,prc", "--out", str(res), "--json", str(root / "metrics.json")],
    )
    for cmd in steps:
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            return {"error": f"{' '.join(cmd[1:3])}: exit {done.returncode}: {done.stderr.strip()[-300:]}"}
    metrics = json.loads((root / "metrics.json").read_text())
    trajectories = {
        str(p.relative_to(res)): untimed(np.loadtxt(p, ndmin=2).tolist()) for p in sorted(res.rglob("*.txt"))
    }
    return {"metrics": untimed(metrics), "trajectories": trajectories}


def record(out: Path, shared: Path = SHARED, full: bool = False) -> None:
    logging.disable(logging.WARNING)
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    FULL["online"] = full
    snap: dict[str, Any] = {"inputs": {}, "written": {}, "errors": {}}
    if full:
        snap["compare"] = compare_record(out / "compare_run")
    if shared.is_dir():
        kitti = shared / "kitti00"
        snap["inputs"]["kitti00"] = dataset_record(kitti)
        for p in sorted((shared / "ouster" / "pcaps").glob("*.pcap")):
            snap["inputs"][f"ouster/{p.name}"] = dataset_record(p)
        for p in sorted((shared / "ouster" / "decoded").glob("*.npz")):
            snap["inputs"][f"ouster/{p.name}"] = dataset_record(p)
            snap["inputs"][f"ouster/{p.name}/staggered"] = dataset_record(p, destaggered=False)
        snap["inputs"]["ouster/decoded"] = dataset_record(shared / "ouster" / "decoded", frames=2)
        for p in sorted((shared / "multisensor").glob("*.pcd")):
            snap["inputs"][f"multisensor/{p.name}"] = dataset_record(p)
        snap["inputs"]["kitti00/order"] = dataset_record(kitti, frames=2, organize_method="order")
        snap["inputs"]["kitti00/beams"] = dataset_record(kitti, frames=1, organize_method="beams")
        vlp16 = shared / "multisensor" / "velodyne_vlp16.pcd"
        snap["inputs"]["multisensor/velodyne_vlp16.pcd/beams"] = dataset_record(vlp16, organize_method="beams")
    else:
        print(f"{shared}: absent; the shared data is not recorded", file=sys.stderr)
    generated = generate_inputs(out / "inputs")
    for name, path in generated.items():
        snap["inputs"][f"generated/{name}"] = dataset_record(path)
        snap["written"][name] = file_digest(path)
    snap["inputs"]["generated/pcd_ring/fixed_cols"] = dataset_record(generated["pcd_ring"], rows=16, cols=1800)
    from data_tools import open_dataset
    from data_tools.datasets import detect_format
    from data_tools.errors import DataError

    kitti_like = generated["kitti_bin"]
    for name, fmt, options in (  # options a format does not take, formats forced or unknown
        ("topic_on_pcd", None, {"topic": "/points"}),
        ("model_on_pcd", None, {"model": "vlp16"}),
        ("staggered_on_pcd", None, {"destaggered": False}),
        ("rows_on_sim", "sim", {"rows": 16}),
        ("unknown_format", "nope", {}),
        ("pcd_as_kitti", "kitti", {}),
        ("pcd_as_bin", "bin", {"cols": 1800, "organize_method": "beams"}),
        ("pcd_as_ouster", "ouster", {}),
    ):
        try:
            open_dataset(kitti_like, fmt, **options)
            snap["errors"][name] = "opened"
        except DataError as exc:
            snap["errors"][name] = {"error": str(exc).replace(str(kitti_like), "<path>")}
    for name, path in bad_inputs(out / "bad").items():
        try:
            snap["errors"][name] = {"format": detect_format(path)}
            snap["errors"][name]["open"] = dataset_record(path)
        except DataError as exc:
            snap["errors"][name] = {"error": str(exc).replace(str(path), "<path>")}
    text = json.dumps(snap, indent=1, sort_keys=True).replace(str(out), "<out>")  # messages name the files
    (out / "snapshot.json").write_text(text)
    frames = sum(len(v.get("frames", [])) for v in snap["inputs"].values())
    print(f"{out / 'snapshot.json'}: {len(snap['inputs'])} inputs, {frames} frames, {time.perf_counter() - t0:.0f} s")


def _diff(a: Any, b: Any, where: str, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{where}/{k}: only in {'B' if k not in a else 'A'}")
            else:
                _diff(a[k], b[k], f"{where}/{k}", out)
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _diff(x, y, f"{where}[{i}]", out)
    elif a != b:
        out.append(f"{where}: {str(a)[:160]} != {str(b)[:160]}")


def compare(a: Path, b: Path) -> int:
    sa = json.loads((a / "snapshot.json").read_text())
    sb = json.loads((b / "snapshot.json").read_text())
    diffs: list[str] = []
    _diff(sa, sb, "", diffs)
    for d in diffs[:200]:
        print(d)
    if diffs:
        print(f"{len(diffs)} differences")
        return 1
    n = sum(len(v.get("frames", [])) for v in sa["inputs"].values())
    print(f"identical ({len(sa['inputs'])} inputs, {n} frames, {len(sa['errors'])} refused inputs)")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("out", type=Path)
    rec.add_argument("--data", type=Path, default=SHARED, help="the shared data (default: ../shared/data)")
    rec.add_argument("--full", action="store_true", help="also the online detectors and prc-slam compare")
    cmp = sub.add_parser("compare")
    cmp.add_argument("a", type=Path)
    cmp.add_argument("b", type=Path)
    args = parser.parse_args(argv)
    if args.cmd == "record":
        record(args.out, args.data, args.full)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
