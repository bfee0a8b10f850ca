"""Open the Rerun web viewer served by ``prc-slam compare --serve-web`` in a real Chromium and check
that its 3-D view draws the point cloud.

Chromium (Debian's ``chromium``) runs *not* headless on a virtual screen (``Xvfb``), with the
software rasteriser (no GPU here); Playwright drives it through ``executable_path`` (no browser
download). The screenshot is written to ``--screenshot`` (default ``out/web_viewer.png``).

Usage: ``python scripts/check_web_viewer.py [SEQUENCE] [--screenshot PATH] [--timeout S]``; exit 0
when the 3-D view shows the cloud, 1 when it stays blank, 77 when Chromium or Xvfb is missing.
"""

from __future__ import annotations

import argparse
import base64
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--ignore-gpu-blocklist",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
    "--window-size=1280,800",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cloud_pixels(png: Path) -> float:
    """Share of the 3-D view's pixels (the middle of the page's left half: no side panel, top bar or
    notifications) that are saturated colours: the class colours of the points, against the
    viewer's grey background and UI."""
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB"), dtype=np.float32) / 255.0
    h, w, _ = img.shape
    view = img[int(0.15 * h) : int(0.9 * h), int(0.2 * w) : int(0.55 * w)]
    mx, mn = view.max(axis=2), view.min(axis=2)
    saturation = (mx - mn) / np.maximum(mx, 1e-6)
    return float(((saturation > 0.35) & (mx > 0.25)).mean())


def start_xvfb() -> tuple[subprocess.Popen, str]:
    for n in range(90, 120):
        if not Path(f"/tmp/.X{n}-lock").exists():
            proc = subprocess.Popen(
                ["Xvfb", f":{n}", "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            time.sleep(1.0)
            if proc.poll() is None:
                return proc, f":{n}"
    raise RuntimeError("no free X display for Xvfb")


def serve(sequence: Path, out: Path, seconds: float, web_port: int, grpc_port: int) -> tuple[subprocess.Popen, str]:
    cli = Path(sys.executable).with_name("prc-slam")
    proc = subprocess.Popen(
        [
            str(cli),
            "compare",
            str(sequence),
            "--out",
            str(out),
            "--log-every",
            "1",
            "--serve-web",
            "--serve-seconds",
            str(seconds),
            "--web-port",
            str(web_port),
            "--grpc-port",
            str(grpc_port),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line and proc.poll() is not None:
            break
        if "web viewer:" in line:
            return proc, line.split("web viewer:", 1)[1].strip()
    proc.kill()
    raise RuntimeError("prc-slam compare --serve-web printed no viewer address")


def check(sequence: Path, screenshot: Path, timeout: float, threshold: float = 0.002) -> tuple[bool, float]:
    from playwright.sync_api import sync_playwright

    xvfb, display = start_xvfb()
    server = None
    try:
        with tempfile.TemporaryDirectory() as tmp:
            server, address = serve(sequence, Path(tmp) / "out", timeout + 60, free_port(), free_port())
            with sync_playwright() as p:
                browser = p.chromium.launch(
                    executable_path=shutil.which("chromium") or "/usr/bin/chromium",
                    headless=False,
                    args=CHROMIUM_ARGS,
                    env={**os.environ, "DISPLAY": display},
                )
                page = browser.new_page(viewport={"width": 1280, "height": 800})
                page.goto(address, wait_until="load", timeout=60_000)
                # the DevTools protocol's capture (through Playwright's CDP session) takes the frame as
                # drawn; Playwright's own screenshot waits for an idle frame, which a busy software
                # rasteriser may not give within its timeout
                cdp = page.context.new_cdp_session(page)
                share = 0.0
                deadline = time.monotonic() + timeout
                screenshot.parent.mkdir(parents=True, exist_ok=True)
                while time.monotonic() < deadline:
                    time.sleep(10)
                    shot = cdp.send("Page.captureScreenshot", {"format": "png"})
                    screenshot.write_bytes(base64.b64decode(shot["data"]))
                    share = cloud_pixels(screenshot)
                    print(f"{time.monotonic() - deadline + timeout:.0f} s: cloud pixels {share:.4f}", flush=True)
                    if share >= threshold:
                        break
                browser.close()
        return share >= threshold, share
    finally:
        if server is not None:
            server.terminate()
            server.wait(timeout=20)
        xvfb.terminate()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence", nargs="?", type=Path, help="input to serve (default: a 3-frame simulated drive)")
    ap.add_argument("--screenshot", type=Path, default=Path("out/web_viewer.png"))
    ap.add_argument("--timeout", type=float, default=100.0, help="seconds to wait for the cloud to render")
    args = ap.parse_args()
    if shutil.which("Xvfb") is None or (shutil.which("chromium") is None and not Path("/usr/bin/chromium").exists()):
        print("skipped: needs Debian's chromium and xvfb (make setup installs them)")
        return 77
    sequence = args.sequence
    with tempfile.TemporaryDirectory() as tmp:
        if sequence is None:
            from data_tools.sim.dataset import write_sequence
            from data_tools.sim.simulator import SimConfig, Simulator

            sequence = write_sequence(Simulator(SimConfig(frames=3, seed=4)), Path(tmp) / "sim")
        ok, share = check(sequence, args.screenshot, args.timeout)
    print(f"{'ok' if ok else 'BLANK'}: {share:.2%} of the 3-D view shows the cloud; screenshot {args.screenshot}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
