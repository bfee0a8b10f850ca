"""``prc-slam bench``: throughput of each stage on its reference input, single process.

Timings are medians of repeated runs; each section also times a fixed numpy yardstick in the
same process so figures from noisy machines can be compared as ratios.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from prc_slam.prc.config import PRCConfig
from prc_slam.prc import prc_block

PAPER_PRC_POINTS_PER_S = 0.13e6  # Lehtola et al. 2019, Sec. IV-D (urban)
PAPER_MAPCLASS_S_PER_MILLION = 1.04  # Wolf et al. 2019, Table 1 (urban area, classification)


def median_seconds(fn: Callable[[], object], repeat: int, warmup: int = 2) -> float:
    """Median wall time of ``fn`` over ``repeat`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def yardstick_seconds(n: int = 213_246, repeat: int = 15) -> float:
    """Time of sorting ``n`` random float32 values: a machine-speed reference."""
    values = np.random.default_rng(0).random(n, dtype=np.float32)
    return median_seconds(lambda: np.sort(values), repeat)


def bench_prc(kitti_dir: Path | None = None, repeat: int = 30) -> dict[str, Any]:
    """PRC (support through classification) on the 99 x 2154 profiler block, and on KITTI frames.

    The profiler block is the synthetic street of :mod:`data_tools.synthetic`; KITTI frames
    are read from ``kitti_dir`` when it exists (the adaptive multi-beam setting is timed too).
    """
    from data_tools.synthetic import profiler_block

    cfg = PRCConfig.preset("urban")
    block = profiler_block(99, 2154, seed=0)
    sec = median_seconds(lambda: prc_block(block.ranges, cfg), repeat)
    yard = yardstick_seconds(block.ranges.size)
    out: dict[str, Any] = {
        "points_per_s": block.ranges.size / sec,
        "block_shape": list(block.ranges.shape),
        "ms_per_block": sec * 1e3,
        "speedup_vs_paper": block.ranges.size / sec / PAPER_PRC_POINTS_PER_S,
        "yardstick_sort_ms": yard * 1e3,
        "ratio_to_yardstick": sec / yard,
    }
    if kitti_dir is not None and (kitti_dir / "velodyne").is_dir():
        from data_tools.kitti import KittiSequence

        seq = KittiSequence(kitti_dir)
        scans = [seq[i] for i in range(min(3, len(seq)))]
        for name, config in (("kitti", cfg), ("kitti_multibeam", PRCConfig.preset("multibeam"))):
            secs = [
                median_seconds(lambda s=s, c=config: prc_block(s.ranges, c, sensor=s.sensor, wrap=True), repeat // 3)
                for s in scans
            ]
            slots = scans[0].ranges.size
            points = float(np.mean([s.n_points for s in scans]))
            out[f"{name}_ms_per_frame"] = float(np.mean(secs)) * 1e3
            out[f"{name}_points_per_s"] = points / float(np.mean(secs))
            out[f"{name}_slots_per_s"] = slots / float(np.mean(secs))
    return out


def bench_sim(frames: int = 10) -> dict[str, Any]:
    """Simulator: Embree ray casting alone, and whole hdl64 urban frames (casting, glass
    re-casts and every noise model), in rays per second."""
    import open3d as o3d

    from data_tools.sim.simulator import SimConfig, Simulator

    sim = Simulator(SimConfig(scene="urban", sensor="hdl64", frames=frames + 1))
    f = sim.frame(0)
    rot, pos = sim.trajectory.poses(f.line_times)
    d = (sim.dirs.transpose(1, 0, 2) @ rot.transpose(0, 2, 1)).transpose(1, 0, 2).reshape(-1, 3)
    o = np.broadcast_to(pos[None], (sim.sensor.model.rows, sim.sensor.model.cols, 3)).reshape(-1, 3)
    rays = o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32))
    cast = median_seconds(lambda: sim._static.cast_rays(rays), 10)
    t0 = time.perf_counter()
    n = sum(sim.frame(i).rays for i in range(1, frames + 1))
    whole = time.perf_counter() - t0
    return {
        "rays_per_s": len(d) / cast,
        "frame_rays_per_s": n / whole,
        "ms_per_hdl64_frame": whole / frames * 1e3,
        "triangles": sim.scene.mesh.n_triangles,
    }


def bench_viz(frames: int = 40, rounds: int = 4) -> dict[str, Any]:
    """Rerun logging overhead with default settings: the raw-vs-prc comparison on a simulated
    hdl64 drive with and without a sink writing an .rrd, in ``rounds`` back-to-back pairs; the
    overhead is the median of the pairs' time ratios (robust to the machine's drift)."""
    import tempfile

    from data_tools.sim.simulator import SimConfig, Simulator
    from prc_slam.config import Config
    from prc_slam.odometry.compare import run_compare
    from prc_slam.scan import Scan
    from prc_slam.viz.sink import RerunSink, VizConfig, open_recording

    sim = Simulator(SimConfig(scene="urban", sensor="hdl64", frames=frames))
    scans = []
    for i in range(frames):
        f = sim.frame(i)
        scans.append(
            Scan(
                f.ranges,
                sim.sensor.model,
                name=f"{i:06d}",
                timestamps=f.slot_times,
                gt_pose=f.pose,
                meta={"frame_time": f.time},
            )
        )
    cfg = Config(prc=PRCConfig.preset("multibeam"))
    plain, logged, size = [], [], 0
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            t0 = time.perf_counter()
            run_compare(iter(scans), cfg)
            plain.append(time.perf_counter() - t0)
            rec, _ = open_recording(rrd=f"{tmp}/b{r}.rrd")
            log = RerunSink(rec, VizConfig()).log_record
            t0 = time.perf_counter()
            run_compare(iter(scans), cfg, on_frame=lambda r_, log=log: log(r_, gt_pose=r_.frame.scan.gt_pose))
            rec.flush()
            logged.append(time.perf_counter() - t0)
            rec.disconnect()
            size = Path(f"{tmp}/b{r}.rrd").stat().st_size
    overhead = float(np.median(np.array(logged) / np.array(plain))) - 1.0
    return {
        "overhead_fraction": overhead,
        "ms_per_frame_plain": min(plain) / frames * 1e3,
        "ms_per_frame_logged": min(logged) / frames * 1e3,
        "rrd_bytes_per_frame": size / frames,
        "rrd_gb_per_1000_frames": size / frames * 1000 / 1e9,
    }


def bench_online(frames: int = 10, profiler_frames: int = 4) -> dict[str, Any]:
    """All four online detectors (coarse, ground, curb, car) on simulated urban frames: hdl64
    sweeps (the criterion's sensor) and profiler-urban blocks of 99 lines (the paper's)."""
    from data_tools.sim.simulator import SimConfig, Simulator
    from prc_slam.online import OnlineDetector
    from prc_slam.scan import Scan

    def run(sensor: str, n: int) -> tuple[float, float]:
        sim = Simulator(SimConfig(scene="urban", sensor=sensor, frames=n + 1))
        scans = [Scan(sim.frame(i).ranges, sim.sensor.model) for i in range(n + 1)]
        det = OnlineDetector()
        det.process(scans[0])  # compile, and a ground height to start from
        t0 = time.perf_counter()
        for scan in scans[1:]:
            det.process(scan)
        sec = (time.perf_counter() - t0) / n
        return float(np.mean([s.n_points for s in scans[1:]])) / sec, sec

    rate, sec = run("hdl64", frames)
    profiler_rate, profiler_sec = run("profiler-urban", profiler_frames)
    return {
        "points_per_s": rate,
        "ms_per_hdl64_frame": sec * 1e3,
        "profiler_points_per_s": profiler_rate,
        "ms_per_profiler_block": profiler_sec * 1e3,
    }


def bench_mapclass(frames: int = 50, repeat: int = 2) -> dict[str, Any]:
    """Map classification (paper 004) end to end on the accumulated map of a simulated hdl64
    urban drive (``frames`` consecutive sweeps at ground-truth poses, > 5 M points)."""
    from data_tools.sim.simulator import SimConfig, Simulator
    from prc_slam.mapclass import accumulate, classify_map
    from prc_slam.scan import Scan

    sim = Simulator(SimConfig(scene="urban", sensor="hdl64", frames=frames))
    sims = [sim.frame(i) for i in range(frames)]
    scans = ((i, Scan(f.ranges, sim.sensor.model, timestamps=f.slot_times), {}) for i, f in enumerate(sims))
    points = accumulate(scans, np.array([f.pose for f in sims]), np.array([f.time for f in sims])).points
    classify_map(points[:20_000])  # compile
    best = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = classify_map(points)
        wall = time.perf_counter() - t0
        if best is None or wall < best[0]:
            best = (wall, result.seconds)
    wall, stages = best
    return {
        "points_per_s": len(points) / wall,
        "points": len(points),
        "seconds": wall,
        "normals_share": stages["normals"] / wall,
        "segmentation_share": stages["segmentation"] / wall,
        **{f"seconds_{k}": v for k, v in stages.items()},
        "paper_seconds_per_million": PAPER_MAPCLASS_S_PER_MILLION,
    }


def run_bench(kitti_dir: Path | None = None) -> dict[str, Any]:
    """All sections implemented so far."""
    return {
        "prc": bench_prc(kitti_dir),
        "online": bench_online(),
        "mapclass": bench_mapclass(),
        "sim": bench_sim(),
        "viz": bench_viz(),
    }
