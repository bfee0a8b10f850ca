"""``prc-slam view``: the viewer found without an activated environment, one line and exit 2 (never a
traceback or a hang) when it cannot be shown, and no process left behind."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.processes import processes_under, wait_until

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a display is a Linux question; reads /proc")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    root = tmp_path_factory.mktemp("viewer") / "sim"
    write_sequence(Simulator(SimConfig(frames=3, seed=4, sensor="vlp16")), root)
    return root


def _view(tiny: Path, **env: str) -> tuple[subprocess.CompletedProcess, int]:
    """``prc-slam view`` as printed in the README: the environment not activated (its bin is not on
    PATH), leading a new SID (its processes are found by that SID)."""
    base = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    base["PATH"] = "/usr/bin:/bin"
    proc = subprocess.Popen(
        [str(Path(sys.executable).with_name("prc-slam")), "view", str(tiny)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
        env={**base, "COLUMNS": "400", **env},
        start_new_session=True,
    )
    try:
        out, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)
        proc.communicate()
        pytest.fail("prc-slam view hung")
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err), proc.pid


@linux
def test_view_without_a_display_is_one_line_exit_2_and_leaves_no_process(tiny):
    """Not a traceback ("Failed to find Rerun Viewer executable in PATH"), nor a viewer that dies
    and a run that hangs: one line, exit 2, no process left."""
    res, sid = _view(tiny)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: view: no display"), res.stderr
    assert "--serve-web" in lines[0] and "--rrd FILE" in lines[0]
    assert wait_until(lambda: not processes_under(sid), 5), processes_under(sid)


@linux
def test_a_viewer_that_ends_at_start_is_one_line_not_a_hang(tiny):
    """A display that is set but cannot be opened (no X server there): the spawned viewer ends at
    once; said with the viewer's own reason, exit 2, no process left."""
    display = ":87"
    if Path("/tmp/.X11-unix/X87").exists():
        pytest.skip("an X server runs on :87")
    res, sid = _view(tiny, DISPLAY=display)
    assert res.returncode == 2, res.stderr
    errors = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith("error: view: the Rerun viewer ended at start"), res.stderr
    assert "Traceback" not in res.stderr
    assert wait_until(lambda: not processes_under(sid), 5), processes_under(sid)


def test_the_viewer_is_found_beside_the_interpreter(tmp_path, monkeypatch):
    """The environment's bin holds ``rerun`` beside ``python``; PATH need not."""
    from prc_slam.viz.sink import rerun_executable

    bin_dir = tmp_path / "venv" / "bin"
    bin_dir.mkdir(parents=True)
    python = bin_dir / "python"
    python.write_text("")
    viewer = bin_dir / ("rerun.exe" if os.name == "nt" else "rerun")
    viewer.write_text("#!/bin/sh\n")
    viewer.chmod(0o755)
    assert rerun_executable(python=str(python), path="") == str(viewer)
    viewer.chmod(0o644)  # not executable: not taken
    assert rerun_executable(python=str(python), path="") != str(viewer)
    # this interpreter's: found with PATH lacking the environment's bin
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    found = rerun_executable()
    assert found is not None and os.access(found, os.X_OK)
    assert subprocess.run([found, "--version"], capture_output=True, timeout=60).returncode == 0


def test_has_display_follows_the_environment(monkeypatch):
    from prc_slam.viz.sink import has_display

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert has_display() == (sys.platform == "darwin" or os.name == "nt")
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    assert has_display()


def test_a_viewer_that_ends_during_the_run_stops_it_with_an_error():
    """A spawned viewer closed mid-run: the next frame's logging raises instead of feeding a stream
    that nobody reads (its sender then blocked forever)."""
    from prc_slam.jobs.common import Viewer
    from prc_slam.viz.sink import ViewerError

    viewer = Viewer()
    viewer._spawned = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    viewer._spawned.wait()
    with pytest.raises(ViewerError, match=r"the Rerun viewer ended during the run \(exit code 3\)"):
        viewer.check()
    viewer.check()  # said once
