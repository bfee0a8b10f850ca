"""``prc-slam replay``."""

from __future__ import annotations

from pathlib import Path

import typer

from prc_slam.cli.common import console, handles_errors


@handles_errors
def replay(
    capture: Path = typer.Argument(..., help="a Velodyne or Ouster packet capture (.pcap, .pcapng)"),
    to: str = typer.Option(
        "udp://127.0.0.1", "--to", help="udp://HOST[:PORT] (default: loopback, the capture's own port)"
    ),
    rate: float = typer.Option(1.0, "--rate", min=0.01, help="speed factor (2: twice as fast)"),
    loop: int = typer.Option(1, "--loop", min=1, help="play the capture this many times"),
    drop: float = typer.Option(0.0, "--drop", min=0.0, max=0.99, help="leave out this fraction of packets at random"),
    seed: int = typer.Option(0, "--seed", min=0, help="seed of --drop"),
) -> None:
    """Send a capture's packets over UDP with their recorded spacing: a stand-in sensor for
    ``prc-slam live``."""
    from prc_slam.live.replay import parse_target
    from prc_slam.live.replay import replay as run_replay

    host, port = parse_target(to, None)
    stats = run_replay(capture, host, port, rate=rate, loop=loop, drop=drop, seed=seed)
    console.print(
        f"sent {stats.sent} packets to {host}:{stats.port} ({stats.dropped} dropped on purpose, {stats.loops} "
        f"loop{'s' if stats.loops != 1 else ''}) in {stats.seconds:.1f} s",
        highlight=False,
    )
