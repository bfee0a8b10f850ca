"""Output files and folders: paths that cannot be written are refused before any work, existing outputs
are replaced (no class files of an earlier run left), an interrupted run says what it left, and files
are written whole or not at all.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def small_kitti(tmp_path_factory) -> Path:
    from data_tools.sim.dataset import SimSequence, export_kitti, write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    sim = tmp_path_factory.mktemp("h30_sim") / "sim"
    write_sequence(Simulator(SimConfig(frames=3, seed=4)), sim)
    out = tmp_path_factory.mktemp("h30_kitti") / "k ü"  # a space and a non-ASCII letter
    export_kitti(SimSequence(sim), out)
    return out


def one_error_line(res) -> str:
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output, res.output
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, res.output
    return errors[0]


@pytest.mark.parametrize(
    "args, needle",
    [
        (["compare", "{kitti}", "--out", "{file}"], "--out: cannot write {file}: it is a file"),
        (["mapclass", "{kitti}", "--out", "{file}"], "--out: cannot write {file}: it is a file"),
        (["batch", "{kitti}", "--out", "{file}"], "--out: cannot write {file}: it is a file"),
        (["classify", "{kitti}", "--labels-out", "{file}"], "--labels-out: cannot write {file}: it is a file"),
        (
            ["classify", "{kitti}", "--labels-out", "{tmp}/lab", "--json", "{file}/m.json"],
            "--json: cannot write {file}/m.json",
        ),
        (
            ["classify", "{kitti}", "--labels-out", "{tmp}/lab", "--las", "{file}/c.las"],
            "--las: cannot write {file}/c.las",
        ),
        (
            ["detect", "{kitti}", "--labels-out", "{tmp}/lab", "--json", "{tmp}"],
            "--json: cannot write {tmp}: it is a directory",
        ),
        (["odometry", "{kitti}", "--poses-out", "{file}/p.txt"], "--poses-out: cannot write {file}/p.txt"),
        (["filter", "{kitti}", "--out", "{file}/x"], "--out: cannot write {file}/x"),
    ],
)
def test_an_output_path_that_cannot_be_written_is_refused_before_any_work(small_kitti, tmp_path, args, needle):
    """An output path that cannot be written (an existing file where a folder goes, a folder where a file goes)
    is refused with a one-line error naming the option, before the first frame, so that ``--json`` and ``compare
    --out`` never lose a finished run's results."""
    from typer.testing import CliRunner

    from prc_slam.cli import app

    afile = tmp_path / "a file"
    afile.write_text("x")
    fill = {"kitti": str(small_kitti), "file": str(afile), "tmp": str(tmp_path)}
    res = CliRunner().invoke(app, [a.format(**fill) for a in args])
    assert needle.format(**fill) in one_error_line(res)
    assert not (tmp_path / "lab").exists()  # refused before the first frame


@pytest.mark.parametrize("where", ["{tmp}", "{file}/run.log"])
def test_a_log_file_that_cannot_be_written_is_one_line(small_kitti, tmp_path, where):
    """``--log-file`` on a directory, or under a file: a traceback before."""
    from typer.testing import CliRunner

    from prc_slam.cli import app

    afile = tmp_path / "a file"
    afile.write_text("x")
    log_file = where.format(tmp=tmp_path, file=afile)
    res = CliRunner().invoke(app, ["--log-file", log_file, "classify", str(small_kitti)])
    assert f"--log-file: cannot write {log_file}" in one_error_line(res)


def test_existing_output_files_and_folders_are_replaced(small_kitti, tmp_path):
    from typer.testing import CliRunner

    from prc_slam.cli import app

    args = ["classify", str(small_kitti), "--labels-out", str(tmp_path / "lab"), "--json", str(tmp_path / "m.json")]
    args += ["--las", str(tmp_path / "c.las")]
    for _ in range(2):
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
    assert len(list((tmp_path / "lab").iterdir())) == 3 and (tmp_path / "m.json").is_file()
    res = CliRunner().invoke(app, ["compare", str(small_kitti), "--out", str(tmp_path / "lab"), "--variants", "raw"])
    assert res.exit_code == 0, res.output


def test_an_interrupted_classify_says_what_it_left(small_kitti, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from prc_slam.cli import app
    from prc_slam.jobs import sinks

    real = sinks.LabelFiles.frame

    def frame(self, step):
        if step.index == 1:
            raise KeyboardInterrupt
        real(self, step)

    monkeypatch.setattr(sinks.LabelFiles, "frame", frame)
    lab, las = tmp_path / "lab", tmp_path / "c.laz"
    res = CliRunner().invoke(app, ["classify", str(small_kitti), "--labels-out", str(lab), "--las", str(las)])
    assert res.exit_code == 130, res.output
    warning = [line for line in res.output.splitlines() if "interrupted after" in line]
    assert warning and "1 of 3 frames" in warning[0] and str(lab) in warning[0] and str(las) in warning[0]
    assert sorted(p.name for p in lab.iterdir()) == ["000000.label"] and not las.exists()


def test_output_files_are_written_whole_or_not_at_all(tmp_path):
    from data_tools.formats.writers import atomic_path, write_label_file

    path = tmp_path / "000000.label"
    with pytest.raises(KeyboardInterrupt), atomic_path(path) as tmp:
        tmp.write_bytes(b"half a file")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    write_label_file(path, np.array([1, 2, 3], dtype=np.uint8))
    assert np.fromfile(path, np.uint32).tolist() == [1, 2, 3] and len(list(tmp_path.iterdir())) == 1
