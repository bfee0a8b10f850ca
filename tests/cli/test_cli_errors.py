"""Every user error is one line ``error: <option or file>: <problem>`` with exit 2, Ctrl-C exits 130,
progress shows off a terminal, tables are never cut, and interrupted recordings are marked partial."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from data_tools.sim.dataset import SimSequence, export_kitti, write_sequence
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("errors") / "sim"
    write_sequence(Simulator(SimConfig(frames=3, seed=4)), root)
    return root


@pytest.fixture(scope="module")
def kitti(tmp_path_factory, sim) -> Path:
    out = tmp_path_factory.mktemp("errors_kitti") / "kitti"
    export_kitti(SimSequence(sim), out)
    return out


def one_error_line(res, *needles: str, code: int = 2) -> str:
    """Assert exit ``code``, no traceback, and exactly one ``error:`` line containing every needle."""
    out = res.output
    assert res.exit_code == code, out
    assert "Traceback" not in out, out
    errors = [line for line in out.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, out
    for needle in needles:
        assert needle in errors[0], out
    return errors[0]


@pytest.mark.parametrize(
    "args, needle",
    [
        (["compare", "{kitti}", "--max-frames", "0", "--out", "{tmp}/X"], "--max-frames"),
        (["odometry", "{kitti}", "--max-frames", "0"], "--max-frames"),
        (["classify", "{kitti}", "--max-frames", "-1"], "--max-frames"),
        (["compare", "{kitti}", "--variants", "", "--out", "{tmp}/X"], "--variants"),
        (["compare", "{kitti}", "--variants", "raw,nope", "--out", "{tmp}/X"], "nope"),
        (["simulate", "--out", "{tmp}/s", "--speed", "-5"], "--speed"),
        (["simulate", "--out", "{tmp}/s", "--seed", "-1"], "--seed"),
        (["classify", "{tmp}/missing"], "missing"),
        (["detect", "{kitti}", "--nope"], "--nope"),
    ],
)
def test_bad_options_are_one_line(tmp_path, kitti, args, needle):
    argv = [a.format(kitti=kitti, tmp=tmp_path) for a in args]
    line = one_error_line(runner.invoke(app, argv), needle)
    assert "http" not in line  # no pydantic URL dumps
    assert not (tmp_path / "X").exists()  # nothing written for a run that never started


def test_malformed_poses_name_the_file_and_line(tmp_path, kitti):
    import shutil

    root = tmp_path / "k"
    shutil.copytree(kitti, root)
    lines = (root / "poses.txt").read_text().splitlines()
    lines[1] = lines[1] + " 7"
    (root / "poses.txt").write_text("\n".join(lines) + "\n")
    one_error_line(runner.invoke(app, ["classify", str(root)]), "poses.txt", "line 2")


def test_empty_sweep_is_counted_and_reported(tmp_path, kitti):
    """An empty sweep after the first keeps its place: counted and said as empty, a label file of
    no entries (it was skipped, leaving no label file: one file per input frame is the contract);
    sweeps without a return before the first with one, whose geometry nothing gives, are skipped
    and said."""
    import shutil

    root = tmp_path / "k"
    shutil.copytree(kitti, root)
    (root / "labels" / "000001.label").unlink()
    (root / "velodyne" / "000001.bin").write_bytes(b"")
    out = tmp_path / "labels"
    res = runner.invoke(app, ["classify", str(root), "--json", str(tmp_path / "m.json"), "--labels-out", str(out)])
    assert res.exit_code == 0, res.output
    warnings = [line for line in res.output.splitlines() if line.startswith("warning:")]
    assert any("000001.bin" in w and "empty sweep" in w for w in warnings), res.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert (m["skipped_frames"], m["empty_frames"], m["frames"]) == (0, 1, 3)
    assert sorted(p.name for p in out.iterdir()) == ["000000.label", "000001.label", "000002.label"]
    assert (out / "000001.label").stat().st_size == 0
    nan = np.full((50, 4), np.nan, np.float32)
    nan.tofile(root / "velodyne" / "000000.bin")
    (root / "labels" / "000000.label").unlink()
    res = runner.invoke(app, ["classify", str(root), "--json", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "m.json").read_text())
    # frames 0 (NaN only) and 1 (empty) come before any sweep with a return: both skipped
    assert (m["skipped_frames"], m["empty_frames"], m["frames"]) == (2, 0, 1)
    assert "000000.bin" in m["skips"][0]["reason"] and "000001.bin" in m["skips"][1]["reason"]


def test_nan_points_become_no_returns_counted(tmp_path, kitti):
    import shutil

    root = tmp_path / "k"
    shutil.copytree(kitti, root)
    f = root / "velodyne" / "000000.bin"
    pts = np.fromfile(f, dtype=np.float32).reshape(-1, 4)
    pts[::50, :3] = np.nan
    pts.tofile(f)
    (root / "labels" / "000000.label").unlink()
    res = runner.invoke(
        app, ["classify", str(root), "--json", str(tmp_path / "m.json"), "--labels-out", str(tmp_path / "lab")]
    )
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["skipped_points"] == len(pts[::50])
    lab = np.fromfile(tmp_path / "lab" / "000000.label", dtype=np.uint32)
    assert lab.size == len(pts)  # one label per input point, NaN points included
    assert (lab[::50] & 0xFFFF == 0).all()  # ... as no return


def test_progress_lines_and_full_tables_off_a_terminal(tmp_path, sim):
    res = runner.invoke(app, ["compare", str(sim), "--out", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    assert "odometry raw | prc: 3/3" in res.output  # a plain progress line, not a bar
    assert "points_to_icp" in res.output and "points_in" in res.output  # headers not cut
    report = (tmp_path / "c" / "report.md").read_text()
    assert "![trajectories](trajectories.png)" in report
    assert "PRC labels against the reference" in report and "| ground |" in report


def test_interrupt_marks_the_recording_partial(tmp_path, sim, monkeypatch):
    from prc_slam.jobs import sinks

    real = sinks.ViewerSink.frame

    def frame(self, step):
        real(self, step)
        if step.index == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(sinks.ViewerSink, "frame", frame)
    rrd = tmp_path / "run.rrd"
    res = runner.invoke(app, ["compare", str(sim), "--out", str(tmp_path / "c"), "--rrd", str(rrd)])
    one_error_line(res, "interrupted", code=130)
    assert not rrd.exists()
    partial = tmp_path / "run.partial.rrd"
    assert partial.is_file()
    import rerun.chunk as rc

    texts = []
    for chunk in rc.RrdReader(str(partial)).store().stream():
        if chunk.entity_path == "/logs":
            rb = chunk.to_record_batch()
            for name in rb.schema.names:
                if name.endswith(":text") or name.endswith("Text"):
                    texts += [str(v) for v in rb.column(name).to_pylist()]
    assert any("interrupted at frame 1" in t for t in texts), texts  # 0-based, as the frame timeline


def _cli() -> str:
    return str(Path(sys.executable).with_name("prc-slam"))


def test_ctrl_c_at_any_moment_is_one_line_and_130(tmp_path, sim):
    for delay in (0.3, 1.0, 2.5, 4.0):  # during start-up (imports), set-up, then mid-run
        proc = subprocess.Popen(
            [_cli(), "compare", str(sim), "--out", str(tmp_path / f"c{delay}")],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "COLUMNS": "200"},
        )
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=120)
        if proc.returncode == 0:  # finished before the signal: nothing to check at this delay
            continue
        assert proc.returncode == 130, err
        assert "Traceback" not in err and "leaked" not in err, err
        errors = [line for line in err.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and errors[0].startswith("error: interrupted"), err  # mid-run: what was written


def test_ctrl_c_inside_a_native_callback_is_delivered_again(monkeypatch):
    """A Ctrl-C that lands in llvmlite's ctypes callback while numba compiles (a cold cache) would
    raise KeyboardInterrupt there, which Python prints ("Exception ignored on calling ctypes
    callback function ... Traceback") and drops; the interrupt is sent again shortly after, once the
    callback has returned; elsewhere it is raised."""
    from types import SimpleNamespace

    from prc_slam import __main__ as launcher

    sent = []
    monkeypatch.setattr(launcher, "REDELIVER_S", 0.0)
    monkeypatch.setattr(launcher, "_interrupted", False)  # (restored after the test)
    monkeypatch.setattr(launcher.os, "kill", lambda pid, sig: sent.append((pid, sig)))
    frame = SimpleNamespace(f_code=SimpleNamespace(co_filename="/x/site-packages/llvmlite/binding/executionengine.py"))
    launcher._on_sigint(signal.SIGINT, frame)  # no exception
    deadline = time.time() + 5
    while not sent and time.time() < deadline:
        time.sleep(0.01)
    assert sent == [(os.getpid(), signal.SIGINT)] and launcher._interrupted
    with pytest.raises(KeyboardInterrupt):
        launcher._on_sigint(signal.SIGINT, SimpleNamespace(f_code=SimpleNamespace(co_filename="/work/prc_slam/x.py")))
