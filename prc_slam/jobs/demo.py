"""The demo's embedded input: a simulated hdl64 urban drive with 1 % outliers, cached on disk."""

from __future__ import annotations

from pathlib import Path

from prc_slam.jobs.progress import Reporter


def simulated_drive(out: Path, frames: int, seed: int, reporter: Reporter | None = None) -> tuple[Path, bool]:
    """Simulate (or reuse) the drive under ``out``; returns its directory and whether it was cached."""
    from data_tools.sim.dataset import SimSequence, write_sequence
    from data_tools.sim.simulator import NoiseConfig, SimConfig, Simulator

    sim_cfg = SimConfig(scene="urban", sensor="hdl64", frames=frames, seed=seed, noise=NoiseConfig(outlier_rate=0.01))
    root = out / f"sim_urban_hdl64_{frames}_seed{seed}"
    cached = (root / "sim.json").is_file() and SimSequence(root).config == sim_cfg
    if not cached:
        task = None if reporter is None else reporter.task("simulating the urban drive", frames)
        write_sequence(Simulator(sim_cfg), root, on_frame=lambda _f: task and task.advance())
    return root, cached
