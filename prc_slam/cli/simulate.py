"""``prc-slam simulate``."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from prc_slam.cli.common import check_outputs, console, handles_errors

Scene = Literal["urban", "forest", "corridor", "street"]
Sensor = Literal[
    "hdl64", "vlp16", "hdl32", "os1-64", "os0-128", "os2-128", "profiler-urban", "profiler-backpack", "als", "tls"
]


@handles_errors
def simulate(
    out: Path = typer.Option(..., help="output directory (the simulator's dataset format)"),
    scene: Scene = typer.Option("urban", help="procedural scene"),
    sensor: Sensor = typer.Option("hdl64", help="simulated sensor"),
    frames: int = typer.Option(200, min=1, help="frames (sweeps, or blocks of scan lines for profilers)"),
    seed: int = typer.Option(0, min=0, help="scene, trajectory and noise seed: same seed, same bytes"),
    outlier_rate: float = typer.Option(0.0, min=0.0, max=1.0, help="background-illumination outliers per slot"),
    wind: float = typer.Option(0.0, min=0.0, help="foliage sway amplitude (m)"),
    speed: float | None = typer.Option(None, min=0.0, help="platform speed (m/s); default 8.33 vehicle, 1.3 walking"),
    kitti: Path | None = typer.Option(None, help="also export KITTI/SemanticKITTI here (spinning sensors)"),
    density: float | None = typer.Option(None, min=0.1, help="als: single-pass pulse density (points/m^2, 8)"),
    pcap: Path | None = typer.Option(
        None, "--pcap", help="vlp16, hdl32: also write the drive as a Velodyne packet capture (UDP to port 2368)"
    ),
) -> None:
    """Simulate a drive or walk with per-slot ground truth (Open3D ray casting); ``als`` and
    ``tls`` write one LAS/LAZ cloud (true class in ``classification``) to OUT (a .laz file or
    a directory). With ``--pcap``, the sensor spins clockwise as a Velodyne does, and its
    sweeps are also written as VLP-16 / HDL-32E data packets (``prc-slam live``, ``replay``)."""
    check_outputs(out=(out, "any"), kitti=(kitti, "dir"))
    if pcap is not None:
        from data_tools.formats.velodyne_packets import capture_format

        capture_format(sensor)  # the one-line error for other sensors
        check_outputs(pcap=(pcap, "file"))
    if sensor in ("als", "tls"):
        from data_tools.sim.airborne import simulate_cloud

        cloud, path = simulate_cloud(sensor, scene, seed, density, out)
        console.print(f"wrote {len(cloud):,} points ({sensor} over {scene}) to {path}", highlight=False)
        return
    from data_tools.sim.dataset import SimSequence, export_kitti, write_sequence
    from data_tools.sim.simulator import NoiseConfig, SimConfig, Simulator
    from prc_slam.jobs.progress import progress

    cfg = SimConfig(
        scene=scene,
        sensor=sensor,
        frames=frames,
        seed=seed,
        wind=wind,
        speed=speed,
        noise=NoiseConfig(outlier_rate=outlier_rate),
        clockwise=pcap is not None,
    )
    sim = Simulator(cfg)
    capture = None
    if pcap is not None:
        from data_tools.formats.velodyne_packets import SimCapture

        capture = SimCapture(pcap, sim.sensor, sensor)

    def on_frame(frame) -> None:
        if capture is not None:
            capture.add(frame)
        task.advance()

    with progress() as reporter:
        task = reporter.task(f"simulating {scene}/{sensor}", frames)
        try:
            write_sequence(sim, out, on_frame=on_frame)
        finally:
            if capture is not None:
                capture.close()
        if kitti is not None:
            seq = SimSequence(out)
            task2 = reporter.task("KITTI export", len(seq))
            export_kitti(seq, kitti, on_frame=lambda _i: task2.advance())
    console.print(
        f"wrote {frames} frames to {out}" + (f" and a KITTI export to {kitti}" if kitti else ""), highlight=False
    )
    if capture is not None:
        console.print(f"wrote {capture.encoder.packets} Velodyne packets to {pcap}", highlight=False)
