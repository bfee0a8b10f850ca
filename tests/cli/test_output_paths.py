"""Every output option of every command is checked before any work: a path that cannot be written
is one line ``error: --option: cannot write PATH: <reason>`` with exit 2, and nothing is run or
written (not the job's other outputs either)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from data_tools.sim.dataset import write_sequence
from data_tools.sim.simulator import SimConfig, Simulator
from prc_slam.cli import app

runner = CliRunner()

#: (command and its input, output option, kind of path, the work it would start)
OUTPUTS = [
    (["classify", "{sim}"], "--labels-out", "dir", "prc_slam.jobs.classify.classify_job"),
    (["classify", "{sim}"], "--las", "file", "prc_slam.jobs.classify.classify_job"),
    (["classify", "{sim}"], "--json", "file", "prc_slam.jobs.classify.classify_job"),
    (["classify", "{sim}"], "--rrd", "file", "prc_slam.jobs.classify.classify_job"),
    (["detect", "{sim}"], "--labels-out", "dir", "prc_slam.jobs.classify.detect_job"),
    (["detect", "{sim}"], "--las", "file", "prc_slam.jobs.classify.detect_job"),
    (["detect", "{sim}"], "--json", "file", "prc_slam.jobs.classify.detect_job"),
    (["detect", "{sim}"], "--rrd", "file", "prc_slam.jobs.classify.detect_job"),
    (["filter", "{sim}", "--out", "{tmp}/filtered"], "--json", "file", "prc_slam.jobs.filter.filter_job"),
    (["filter", "{sim}"], "--out", "any", "prc_slam.jobs.filter.filter_job"),
    (["odometry", "{sim}"], "--poses-out", "file", "prc_slam.jobs.odometry.run_odometry"),
    (["odometry", "{sim}"], "--json", "file", "prc_slam.jobs.odometry.run_odometry"),
    (["odometry", "{sim}"], "--rrd", "file", "prc_slam.jobs.odometry.run_odometry"),
    (["compare", "{sim}", "--out", "{tmp}/c"], "--json", "file", "prc_slam.jobs.odometry.run_odometry"),
    (["compare", "{sim}", "--out", "{tmp}/c"], "--rrd", "file", "prc_slam.jobs.odometry.run_odometry"),
    (["compare", "{sim}"], "--out", "dir", "prc_slam.jobs.odometry.run_odometry"),
    (["mapclass", "{sim}", "--out", "{tmp}/m"], "--json", "file", "prc_slam.jobs.mapclass.mapclass_job"),
    (["mapclass", "{sim}", "--out", "{tmp}/m"], "--rrd", "file", "prc_slam.jobs.mapclass.mapclass_job"),
    (["mapclass", "{sim}"], "--out", "dir", "prc_slam.jobs.mapclass.mapclass_job"),
    (["batch", "{tmp}/plan.yaml"], "--out", "dir", "prc_slam.jobs.batch.load_plan"),
    (["simulate", "--frames", "2"], "--out", "any", "data_tools.sim.simulator.Simulator"),
    (["simulate", "--frames", "2", "--out", "{tmp}/s"], "--kitti", "dir", "data_tools.sim.simulator.Simulator"),
    (["bench"], "--json", "file", "prc_slam.jobs.bench.run_bench"),
    (["demo", "--frames", "2"], "--out", "dir", "prc_slam.jobs.demo.simulated_drive"),
    (["live", "velodyne://2368"], "--json", "file", "prc_slam.live.run.run_live"),
    (["live", "velodyne://2368"], "--poses-out", "file", "prc_slam.live.run.run_live"),
    (["live", "velodyne://2368"], "--labels-out", "dir", "prc_slam.live.run.run_live"),
    (["live", "velodyne://2368"], "--rrd", "file", "prc_slam.live.run.run_live"),
    ([], "--log-file", "file", "prc_slam.jobs.classify.classify_job"),  # before the command: prc-slam OPT classify
]


def unwritable_paths(tmp: Path) -> dict[str, Path]:
    """Paths no one can write: under Linux's ``/proc`` (which the permission bits call writable
    for root) and under a regular file."""
    paths = {"under a file": tmp / "a_file" / "x"}
    if Path("/proc/self").is_dir():
        paths["in /proc"] = Path("/proc/nope/x")
    return paths


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("outputs") / "sim"
    write_sequence(Simulator(SimConfig(frames=2, seed=4)), root)
    return root


@pytest.mark.parametrize("where", ["in /proc", "under a file"])
@pytest.mark.parametrize("args, option, kind, work", OUTPUTS, ids=lambda v: v if isinstance(v, str) else None)
def test_an_unwritable_output_stops_the_command_before_any_work(
    tmp_path, sim, monkeypatch, where, args, option, kind, work
):
    paths = unwritable_paths(tmp_path)
    if where not in paths:
        pytest.skip("no /proc here")
    (tmp_path / "a_file").write_text("a file, not a directory")
    (tmp_path / "plan.yaml").write_text(f"job: {{kind: classify}}\ninputs: [{sim}]\n")
    module, name = work.rsplit(".", 1)

    def started(*_args, **_kwargs):
        raise AssertionError(f"{work} ran although {option} cannot be written")

    monkeypatch.setattr(__import__(module, fromlist=[name]), name, started)
    monkeypatch.chdir(tmp_path)  # default output directories (out/...) would appear here
    before = sorted(os.listdir(tmp_path))
    bad = paths[where].with_suffix(".json" if kind == "file" else "")
    argv = [a.format(sim=sim, tmp=tmp_path) for a in args]
    argv = [option, str(bad), "classify", str(sim)] if option == "--log-file" else [*argv, option, str(bad)]
    res = runner.invoke(app, argv)
    assert res.exit_code == 2, res.output
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert errors == [errors[0]] and errors[0].startswith(f"error: {option}: cannot write {bad}: "), res.output
    assert "Traceback" not in res.output and "[Errno" not in res.output
    assert sorted(os.listdir(tmp_path)) == before  # no output started


@pytest.mark.parametrize("kind, path, reason", [("dir", "a_file", "is a file"), ("file", ".", "is a directory")])
def test_a_file_for_a_directory_and_the_reverse(tmp_path, kind, path, reason):
    from prc_slam.cli.common import unwritable

    (tmp_path / "a_file").write_text("x")
    assert reason in unwritable(tmp_path / path, kind)


def test_writable_paths_pass_and_nothing_is_left_behind(tmp_path):
    from prc_slam.cli.common import check_outputs

    (tmp_path / "old.json").write_text("kept")
    check_outputs(
        json_path=(tmp_path / "new" / "deeper" / "m.json", "file"),
        labels_out=(tmp_path / "labels", "dir"),
        out=(tmp_path, "any"),
        rrd=(tmp_path / "old.json", "file"),
        las=(None, "file"),
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.json"]
    assert (tmp_path / "old.json").read_text() == "kept"


def test_filter_refuses_an_output_format_the_input_cannot_give_before_compiling(sim, tmp_path, monkeypatch):
    """A bag/MCAP output needs a bag/MCAP input (its topic and frame id): a simulated folder with
    ``--out x.mcap`` is refused before the kernels compile (it took ~30 s of compiling first)."""
    import prc_slam.prc.algorithm as algorithm

    def compiled(*_args, **_kwargs):
        raise AssertionError("the kernels were compiled before the output format was checked")

    monkeypatch.setattr(algorithm, "warm_up", compiled)
    res = runner.invoke(app, ["filter", str(sim), "--out", str(tmp_path / "x.mcap")])
    assert res.exit_code == 2, res.output
    assert "needs a ROS 1/2 or MCAP input" in res.output and "Traceback" not in res.output
