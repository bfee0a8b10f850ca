"""The next frame made in a forked process (``prc_slam.util.frame_process``): the same run as on a
thread, errors, logs, warnings and the source's bookkeeping passed back, the child ended."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from prc_slam.util.frame_process import ForkedNextFrame, FrameProcessEnded, can_fork

pytestmark = pytest.mark.skipif(os.name != "posix", reason="fork is POSIX only")


class _Frames:
    """A stand-in for :class:`prc_slam.pipeline.NextFrame`: frames 1, 2, an error at 3, then 4
    and the end; logs a line and warns for each frame, counts into ``book``."""

    def __init__(self, book: dict, warned: list[str], broken: BaseException) -> None:
        self.i, self.book, self.warned, self.broken = 0, book, warned, broken
        self.charged: tuple = ()
        self.seconds = 0.0

    def take(self):
        self.i += 1
        self.seconds = 0.001 * self.i
        self.charged = ((float(self.i), float(self.i) + 0.5),)
        if self.i == 3:
            raise self.broken
        logging.getLogger("prc_slam.test_child").warning("made frame %d", self.i)
        self.warned.append(f"frame {self.i} warned")
        self.book["frames"] = self.i
        return None if self.i > 4 else {"frame": self.i, "pid": os.getpid()}


class _Unpicklable(Exception):
    def __init__(self, a, b):
        super().__init__(f"{a}/{b}")
        self.lock = threading.Lock()  # cannot be pickled (whatever pickling support is installed)


@pytest.mark.parametrize("broken", [ValueError("frame 3 is broken"), _Unpicklable("x", "y")])
def test_forked_frames_errors_logs_warnings_and_state(caplog, broken):
    book: dict = {}
    warned: list[str] = []
    got_state: list[dict] = []
    said: list[str] = []
    frames = ForkedNextFrame(
        lambda: _Frames(book, warned, broken), lambda: dict(book), got_state.append, warned, said.append
    )
    try:
        with caplog.at_level(logging.WARNING, logger="prc_slam.test_child"):
            first = frames.take()
        assert first["frame"] == 1 and first["pid"] != os.getpid()  # made in the child
        assert "made frame 1" in caplog.text and said == ["frame 1 warned"] and got_state[-1] == {"frames": 1}
        assert book == {}  # the child's bookkeeping reaches the caller through absorb only
        frames.start()
        assert frames.wait() == pytest.approx(0.002) and frames.charged == ((2.0, 2.5),)
        assert frames.take()["frame"] == 2
        if isinstance(broken, ValueError):
            with pytest.raises(ValueError, match="frame 3 is broken"):
                frames.take()
        else:  # an exception that cannot cross: its type and text in a RuntimeError
            with pytest.raises(RuntimeError, match="_Unpicklable: x/y"):
                frames.take()
        assert frames.take()["frame"] == 4
        assert frames.take() is None
        assert said == ["frame 1 warned", "frame 2 warned", "frame 4 warned", "frame 5 warned"]
    finally:
        frames.close()
    assert not frames._proc.is_alive() and frames._proc.exitcode == 0


def test_a_child_that_dies_is_an_error_raised_by_take():
    def make():
        os._exit(3)

    frames = ForkedNextFrame(make, dict, lambda s: None, [], lambda s: None)
    try:
        with pytest.raises(FrameProcessEnded, match=r"process making the frames ended \(exit code 3\)"):
            frames.take()
    finally:
        frames.close()
    # gone between frames: start() and wait() do not raise, the next take() does
    frames = ForkedNextFrame(make, dict, lambda s: None, [], lambda s: None)
    frames._proc.join(5.0)
    try:
        frames.start()
        assert frames.wait() == 0.0
        with pytest.raises(FrameProcessEnded):
            frames.take()
    finally:
        frames.close()


def _compare(root: Path, out: Path, *extra: str) -> tuple[dict, str]:
    """``prc-slam compare`` in a fresh interpreter (numba's threads not yet started: the fork is
    taken there, whatever earlier tests in this process did)."""
    cmd = [sys.executable, "-m", "prc_slam.__main__", "compare", str(root), "--variants", "raw,prc", "--out", str(out)]
    res = subprocess.run([*cmd, *extra], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    return json.loads((out / "metrics.json").read_text()), res.stdout + res.stderr


def test_compare_in_a_process_is_the_run_on_a_thread(tmp_path):
    """Poses, counts and the skipped frame are the same whether the next frame is made in a
    forked process (default) or on a thread; the metrics say which."""
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    root = tmp_path / "seq"
    write_sequence(Simulator(SimConfig(frames=8, seed=4, sensor="vlp16")), root)
    (root / "frames" / "000003.npz").write_bytes(b"PK\x03\x04 cut short")  # one unreadable frame
    (tmp_path / "thread.yaml").write_text("odometry:\n  overlap_process: false\n")
    forked, said = _compare(root, tmp_path / "fork")
    threaded, _ = _compare(root, tmp_path / "thread", "--config", str(tmp_path / "thread.yaml"))
    assert forked["next_frame_made_in"] == "process" and threaded["next_frame_made_in"] == "thread"
    assert forked["skipped_frames"] == threaded["skipped_frames"] == 1
    assert "skipped frame 3" in said  # the child's warning, said by the caller
    for name in ("raw", "prc"):
        a = np.loadtxt(tmp_path / "fork" / f"{name}_poses_tum.txt")
        b = np.loadtxt(tmp_path / "thread" / f"{name}_poses_tum.txt")
        assert a.shape == (7, 8)
        np.testing.assert_allclose(a, b, atol=1e-9)
        for key in ("points_in", "points_to_icp"):
            assert forked["variants"][name][key] == threaded["variants"][name][key]
    shutil.rmtree(root)


_DYING = """
import os, sys
from pathlib import Path
import prc_slam.jobs.odometry as job
from prc_slam.config import Config

parent, opened = os.getpid(), job.open_input

class Dying:  # reading frame 4 kills the process making the frames (the child)
    def __init__(self, ds):
        self.ds = ds
    def __len__(self):
        return len(self.ds)
    def __getitem__(self, i):
        if i == 4 and os.getpid() != parent:
            os._exit(9)
        return self.ds[i]
    def __getattr__(self, name):
        return getattr(self.ds, name)

def open_input(*a, **k):
    ds, n = opened(*a, **k)
    return Dying(ds), n

job.open_input = open_input
run, _ = job.run_odometry(Path(sys.argv[1]), Config(), ["raw", "prc"])
job.write_outputs(run, Config(), Path(sys.argv[2]), "dying")
"""


def test_a_frame_process_that_dies_ends_the_run_with_its_outputs(tmp_path):
    """The child killed while reading frame 4 (the OOM killer, a crash in a reader's library):
    the run stops there, said, and every output covers the frames registered before."""
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    root = tmp_path / "seq"
    write_sequence(Simulator(SimConfig(frames=8, seed=4, sensor="vlp16")), root)
    script = tmp_path / "dying.py"
    script.write_text(_DYING)
    res = subprocess.run(
        [sys.executable, str(script), str(root), str(tmp_path / "out")], capture_output=True, text=True, timeout=600
    )
    assert res.returncode == 0, res.stdout + res.stderr
    said = " ".join((res.stdout + res.stderr).split())  # the console wraps long lines
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["next_frame_made_in"] == "process"
    # the child reads a frame ahead: frame 3 is lost with it when it was made before frame 4's read
    ended = metrics["ended_early"]
    k = int(ended.rsplit("before frame ", 1)[1])
    assert k in (3, 4) and ended.startswith("the process making the frames ended (exit code 9)")
    assert f"the outputs cover frames 0 to {k - 1}" in said
    assert {v["frames"] for v in metrics["variants"].values()} == {k}
    assert len(np.loadtxt(tmp_path / "out" / "prc_poses_tum.txt")) == k
    assert "**Ended early**" in (tmp_path / "out" / "report.md").read_text()


def test_can_fork_says_why_not_once_numba_threads_run():
    """In this (pytest) process numba's parallel threads may already run; either way the answer
    is consistent with numba's own state."""
    from numba.np.ufunc import parallel

    ok, why = can_fork()
    assert ok == (not parallel._is_initialized) and (ok or "OpenMP" in why)
