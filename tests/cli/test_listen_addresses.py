"""Everything the project serves listens on the loopback unless ``--bind`` says otherwise: the Rerun
gRPC server and web viewer of ``--serve-web``, and the local Dask cluster of ``batch`` (scheduler,
workers, dashboard). The listening sockets are read from ``/proc/net/tcp`` and ``tcp6``."""

from __future__ import annotations

import ipaddress
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests.processes import processes_under, wait_until

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def _address(hex_address: str, family: int) -> tuple[str, int]:
    host, port = hex_address.split(":")
    raw = bytes.fromhex(host)
    if family == socket.AF_INET:
        raw = raw[::-1]
    else:  # four 32-bit words, each in host (little-endian) order
        raw = b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4))
    return socket.inet_ntop(family, raw), int(port, 16)


def listening(pids: list[int]) -> dict[int, tuple[str, int]]:
    """The TCP sockets the processes ``pids`` listen on: inode -> (address, port)."""
    inodes = set()
    for pid in pids:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                link = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if link.startswith("socket:["):
                inodes.add(int(link[8:-1]))
    found = {}
    for name, family in (("tcp", socket.AF_INET), ("tcp6", socket.AF_INET6)):
        try:
            lines = Path(f"/proc/net/{name}").read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if fields[3] == "0A" and int(fields[9]) in inodes:  # LISTEN
                found[int(fields[9])] = _address(fields[1], family)
    return found


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _loopback(host: str) -> bool:
    address = ipaddress.ip_address(host)
    mapped = getattr(address, "ipv4_mapped", None)
    return (mapped or address).is_loopback


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    root = tmp_path_factory.mktemp("listen") / "sim"
    write_sequence(Simulator(SimConfig(frames=3, seed=4, sensor="vlp16")), root)
    return root


@pytest.mark.parametrize("command", ["compare", "view"])
def test_serve_web_listens_on_the_loopback_only(tiny, tmp_path, command):
    """The gRPC server and the web viewer listen on the loopback, not 0.0.0.0 (every interface). ``view``
    runs without a display here: with ``--serve-web`` it needs none."""
    web, grpc = _free_port(), _free_port()
    err = tmp_path / "err.txt"
    args = [str(Path(sys.executable).with_name("prc-slam")), command, str(tiny), "--serve-web"]
    args += ["--serve-seconds", "120", "--web-port", str(web), "--grpc-port", str(grpc)]
    if command == "compare":
        args += ["--out", str(tmp_path / "c")]
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.Popen(
        args, stdout=subprocess.DEVNULL, stderr=err.open("w"), stdin=subprocess.DEVNULL, env=env, start_new_session=True
    )
    try:
        assert wait_until(lambda: "still serving" in err.read_text() or proc.poll() is not None, 300)
        assert proc.poll() is None, err.read_text()
        sockets = listening(processes_under(proc.pid))
        ports = {port for _, port in sockets.values()}
        assert {web, grpc} <= ports, (sockets, err.read_text())
        assert all(_loopback(host) for host, _ in sockets.values()), sockets
        assert "serving on" not in err.read_text()  # no exposure warning on the loopback
    finally:
        proc.send_signal(signal.SIGINT)  # stops serving
        proc.wait(timeout=60)
    assert "Traceback" not in err.read_text()
    assert wait_until(lambda: not processes_under(proc.pid), 10), processes_under(proc.pid)


def test_bind_exposes_with_one_warning(tiny, tmp_path):
    """``--bind 0.0.0.0`` listens on every interface and says who can now connect."""
    web, grpc = _free_port(), _free_port()
    args = [str(Path(sys.executable).with_name("prc-slam")), "compare", str(tiny), "--out", str(tmp_path / "c")]
    args += ["--serve-web", "--serve-seconds", "0", "--web-port", str(web), "--grpc-port", str(grpc)]
    res = subprocess.run(
        [*args, "--bind", "0.0.0.0"],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "COLUMNS": "400"},
    )
    assert res.returncode == 0, res.stderr
    warned = [line for line in res.stderr.splitlines() if line.startswith("warning: serving on 0.0.0.0")]
    assert len(warned) == 1 and f"{web}/{grpc}" in warned[0] and "can watch and send data" in warned[0]


def test_the_local_dask_cluster_listens_on_the_loopback_only():
    """The dashboard of ``batch`` listens on the loopback, not on every interface."""
    pytest.importorskip("distributed")
    import psutil  # (a dependency of distributed)

    from prc_slam.jobs.distributed import has_dashboard, open_client

    me = psutil.Process()

    def pids() -> list[int]:
        return [me.pid, *(p.pid for p in me.children(recursive=True))]

    before = set(listening(pids()))
    port = _free_port()
    with open_client(workers=1, note=lambda s: None, dashboard_port=port) as client:
        sockets = {k: v for k, v in listening(pids()).items() if k not in before}
        scheduler_port = int(client.scheduler.address.rsplit(":", 1)[1])
    ports = {p for _, p in sockets.values()}
    assert scheduler_port in ports and (port in ports or not has_dashboard()), sockets
    assert all(_loopback(host) for host, _ in sockets.values()), sockets
