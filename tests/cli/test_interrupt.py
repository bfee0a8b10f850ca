"""Ctrl-C and SIGTERM end a run with what its finished frames produced, and leave no process behind.

``prc-slam compare`` runs as a subprocess that leads a new SID (``start_new_session``), so every
process it starts (the forked frame process, a web viewer's server) is found by that SID.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from tests.processes import processes_under, wait_until

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

FRAMES = 200  # long enough that the first progress line (after 10 s) comes well before the end


def gone(pid: int) -> bool:
    """Whether ``pid`` has ended (a zombie left for a parent that does not reap counts as ended)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    root = tmp_path_factory.mktemp("interrupt") / "sim"
    write_sequence(Simulator(SimConfig(frames=FRAMES, seed=4, sensor="vlp16")), root)
    return root


def _cli() -> str:
    return str(Path(sys.executable).with_name("prc-slam"))


def _start(args: list[str], err: Path, command: list[str] | None = None) -> subprocess.Popen:
    env = {**os.environ, "COLUMNS": "400"}  # one line per message
    return subprocess.Popen(
        [*(command or [_cli()]), *args],
        stdout=subprocess.DEVNULL,
        stderr=err.open("w"),
        stdin=subprocess.DEVNULL,
        env=env,
        start_new_session=True,
    )


def _wait_for_progress(proc: subprocess.Popen, err: Path) -> None:
    """Until the first progress line (some frames done) or the end of the process."""
    assert wait_until(lambda: f"/{FRAMES}," in err.read_text() or proc.poll() is not None, 300), err.read_text()
    assert proc.poll() is None, f"the run ended before it could be interrupted: {err.read_text()}"


def _error_lines(err: Path) -> list[str]:
    text = err.read_text()
    assert "Traceback" not in text, text
    return [line for line in text.splitlines() if line.startswith("error:")]


def _check_partial(out: Path, line: str) -> int:
    """The outputs of an interrupted run: marked, covering the frames the line names."""
    metrics = json.loads((out / "metrics.json").read_text())
    k = metrics["interrupted_at_frame"]
    assert metrics["interrupted"] is True and 0 < k < FRAMES
    assert metrics["frames"] == k and {v["frames"] for v in metrics["variants"].values()} == {k}
    assert len(np.loadtxt(out / "prc_poses_tum.txt")) == k and len(np.loadtxt(out / "raw_poses_kitti.txt")) == k
    assert (out / "report.md").read_text().startswith(f"# Interrupted at frame {k} of {FRAMES}")
    assert line.startswith(f"error: interrupted at frame {k} of {FRAMES}: wrote {out / 'report.md'}"), line
    assert f"trajectories ({k} frames)" in line
    return k


def test_ctrl_c_in_compare_writes_the_frames_done(drive, tmp_path):
    """Ctrl-C after k frames writes the outputs of those frames, not only ``error: interrupted``."""
    out, err = tmp_path / "c", tmp_path / "err.txt"
    proc = _start(["compare", str(drive), "--out", str(out)], err)
    _wait_for_progress(proc, err)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=120) == 130, err.read_text()
    (line,) = _error_lines(err)
    _check_partial(out, line)
    assert wait_until(lambda: not processes_under(proc.pid), 10), processes_under(proc.pid)


def test_sigterm_ends_compare_like_ctrl_c_and_leaves_no_process(drive, tmp_path):
    """SIGTERM ends the run with a message and ends its forked frame process too."""
    out, err = tmp_path / "c", tmp_path / "err.txt"
    proc = _start(["compare", str(drive), "--out", str(out)], err)
    _wait_for_progress(proc, err)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=120) == 143, err.read_text()
    (line,) = _error_lines(err)
    _check_partial(out, line)
    assert wait_until(lambda: not processes_under(proc.pid), 10), processes_under(proc.pid)


_SECOND_CTRL_C = """
import os, signal, sys
import prc_slam.jobs.odometry as job
from prc_slam.__main__ import main

written = job.write_outputs

def write_outputs(*args, **kwargs):  # a second Ctrl-C arrives while the results are written
    os.kill(os.getpid(), signal.SIGINT)
    return written(*args, **kwargs)

job.write_outputs = write_outputs
sys.argv = ["prc-slam", *sys.argv[1:]]
main()
"""


def test_a_second_ctrl_c_while_writing_ends_the_process(drive, tmp_path):
    script = tmp_path / "second.py"
    script.write_text(textwrap.dedent(_SECOND_CTRL_C))
    out, err = tmp_path / "c", tmp_path / "err.txt"
    proc = _start(["compare", str(drive), "--out", str(out)], err, [sys.executable, str(script)])
    _wait_for_progress(proc, err)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=120) == 130, err.read_text()
    (line,) = _error_lines(err)
    assert line.startswith("error: interrupted at frame ") and "interrupted again while writing the results" in line
    assert wait_until(lambda: not processes_under(proc.pid), 10), processes_under(proc.pid)


_PARENT = """
import os, sys, time
from prc_slam.util.frame_process import ForkedNextFrame

class Slow:  # frames that take a while, as a long sweep read would
    charged, seconds = (), 0.0

    def take(self):
        time.sleep(0.2)
        return os.getpid()

frames = ForkedNextFrame(Slow, dict, lambda s: None, [], print)
print(frames.take(), flush=True)  # the child's pid
frames.start()  # the child is making the next frame when the parent is killed
time.sleep(600)
"""


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_the_frame_process_dies_with_its_parent(tmp_path, sig):
    """A child that kept its copy of the parent's end of the pipe would wait on it forever
    once the parent was killed (an orphan at 100 % of nothing, holding the source's files)."""
    script = tmp_path / "parent.py"
    script.write_text(_PARENT)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        assert child != parent.pid and not gone(child)
        parent.send_signal(sig)
        parent.wait(timeout=30)
        assert wait_until(lambda: gone(child), 10), f"the frame process {child} outlived its parent"
    finally:
        parent.kill()
        parent.wait()


_BLOCKED = """
import sys
import numpy as np
import rerun as rr
import prc_slam.cli
from prc_slam import __main__ as launcher
def blocked():  # a stream to a viewer that is not there: the sender blocks once its queue is full
    rec = rr.RecordingStream("blocked")
    rec.set_sinks(rr.GrpcSink(f"rerun+http://127.0.0.1:{sys.argv[1]}/proxy"))
    points = np.random.default_rng(0).random((200_000, 3), dtype=np.float32)
    for i in range(100_000):
        rec.set_time("frame", sequence=i)
        rec.log("points", rr.Points3D(points))
        print(i, flush=True)

prc_slam.cli.app = blocked
launcher.main()
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupt_ends_a_run_blocked_in_native_code(tmp_path, sig):
    """With the Rerun viewer gone, the sender blocks inside a native call ("Sender has been
    blocked ...") where no Python signal handler runs; Ctrl-C or SIGTERM must still end the run."""
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    script = tmp_path / "blocked.py"
    script.write_text(_BLOCKED)
    out = tmp_path / "out.txt"
    proc = subprocess.Popen(
        [sys.executable, str(script), str(port)],
        stdout=out.open("w"),
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        # the queue fills within a few hundred frames; then no frame is logged for seconds
        def stalled() -> bool:
            before = out.read_text().count("\n")
            time.sleep(2.0)
            return before > 0 and out.read_text().count("\n") == before

        assert wait_until(stalled, 120), "the sender never blocked"
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == (130 if sig == signal.SIGINT else 143), err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "stuck in a native call" in errors[0], err
