"""The README's examples run as written.

Python blocks: test functions under pytest (in a fresh directory, first writing their golden files,
then checking against them), everything else in one namespace. Bash blocks: every command, in order,
in a fresh directory that holds the repository's ``.venv`` and ``examples/`` and the demo's cached
drive (the one ``make demo`` simulates), except ``make demo``/``make test`` themselves and the commands
the README marks as needing a display or serving until Ctrl-C.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
# the markers a README command carries when it cannot run unattended
SKIP_MARKERS = ("# needs a display", "# serves until Ctrl-C")
# the two commands the README opens with (`make test` runs this file)
MAKE_TARGETS = ("make demo", "make test")
DEMO_FRAMES, DEMO_SEED = 150, 0


def python_blocks() -> list[str]:
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def bash_commands(text: str) -> list[str]:
    """Every command of the ```bash blocks of ``text``, in order: continuation lines joined, comment
    lines dropped, a command's trailing comment kept (it may carry a skip marker)."""
    commands: list[str] = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        pending = ""
        for line in block.splitlines():
            stripped = line.strip()
            if not pending and (not stripped or stripped.startswith("#")):
                continue
            if stripped.endswith("\\"):
                pending += stripped[:-1].rstrip() + " "
                continue
            commands.append(pending + stripped)
            pending = ""
        assert not pending, f"README: a bash block ends in a continuation line: {pending!r}"
    return commands


def is_skipped(command: str) -> bool:
    return command.startswith(MAKE_TARGETS) or any(marker in command for marker in SKIP_MARKERS)


def test_bash_commands_parses_blocks():
    text = (
        "```bash\n# a comment\nmake demo   # sets up\n"
        ".venv/bin/a x \\\n    --y 1\n\n.venv/bin/b  # needs a display\n```\n"
    )
    assert bash_commands(text) == ["make demo   # sets up", ".venv/bin/a x --y 1", ".venv/bin/b  # needs a display"]
    assert [is_skipped(c) for c in bash_commands(text)] == [True, False, True]


def test_readme_has_the_library_examples():
    blocks = python_blocks()
    joined = "\n".join(blocks)
    for name in ("Preprocessor", "PRCKissICP", "trajectory_regression", "Pipeline"):
        assert name in joined


def test_readme_commands_paste_as_written():
    """Skipped commands are only the two make targets and the marked ones; every other command calls the
    project's tools through .venv/bin/ (nothing bare such as ``evo_ape``) and reads no placeholder input."""
    commands = bash_commands((ROOT / "README.md").read_text())
    assert commands[:2] == [c for c in commands if c.startswith(MAKE_TARGETS)]
    assert [c.split("#")[0].strip() for c in commands[:2]] == list(MAKE_TARGETS)
    for command in commands[2:]:
        # a viewer needs a display and a web viewer serves until stopped: those, and only those, are marked
        viewer = re.search(r"bin/rerun\b|prc-slam view\b|--serve-web|--spawn\b", command)
        serving = viewer or re.search(r"--connect\b|prc-slam (live|replay)\b", command)
        if viewer:
            assert is_skipped(command), f"README: mark this command {SKIP_MARKERS}: {command}"
        if is_skipped(command):
            assert serving, f"README: a command marked as not runnable unattended runs unattended: {command}"
    run = [c for c in commands if not is_skipped(c)]
    assert len(run) >= 8
    for command in run:
        for part in re.split(r"&&|;|\bdo\b|\bthen\b", command.split(" #")[0]):
            words = part.split()
            if not words or words[0] in ("for", "done", "fi", "if"):
                continue
            assert words[0].startswith(".venv/bin/"), f"README command does not paste: {command}"
    for placeholder in ("my_drive", "city.laz", "drive.mcap"):
        assert not any(placeholder in c for c in run), placeholder


def prepared_workdir(tmp_path: Path) -> Path:
    """A fresh working directory as a newcomer's checkout after ``make demo``: the venv and the
    examples, an empty out/ and the demo's drive (simulated once into out/demo like ``make demo`` does
    and reused from there)."""
    from prc_slam.jobs.demo import simulated_drive

    drive, _cached = simulated_drive(ROOT / "out" / "demo", DEMO_FRAMES, DEMO_SEED)
    work = tmp_path / "checkout"
    (work / "out" / "demo").mkdir(parents=True)
    (work / ".venv").symlink_to(ROOT / ".venv")
    shutil.copytree(ROOT / "examples", work / "examples")
    (work / "out" / "demo" / drive.name).symlink_to(drive)
    return work


@pytest.mark.skipif(not (ROOT / ".venv" / "bin" / "prc-slam").exists(), reason="needs make setup's .venv")
def test_readme_commands_run(tmp_path):
    work = prepared_workdir(tmp_path)
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MPLBACKEND"] = "Agg"
    commands = [c for c in bash_commands((ROOT / "README.md").read_text()) if not is_skipped(c)]
    for command in commands:
        res = subprocess.run(
            ["bash", "-c", "set -eo pipefail; " + command],
            cwd=work,
            env=env,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert res.returncode == 0, (
            f"README command failed ({res.returncode}): {command}\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
        )


def test_readme_pytest_examples_pass(tmp_path):
    tests = [b for b in python_blocks() if re.search(r"^def test_", b, flags=re.M)]
    assert tests
    (tmp_path / "test_from_readme.py").write_text("\n\n".join(tests))
    for extra in (["--update-golden"], []):  # write the golden file, then compare against it
        res = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_from_readme.py", *extra],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert res.returncode == 0, res.stdout + res.stderr
    assert (tmp_path / "golden" / "test_my_odometry.txt").is_file()


def test_readme_library_examples_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "readme"}
    for block in python_blocks():
        if re.search(r"^def test_", block, flags=re.M):
            continue
        exec(compile(block, "README.md", "exec"), namespace)
    out = capsys.readouterr().out
    assert "points ->" in out and "kept" in out
    assert "ground recall" in out
    # the drive moves: the odometry's path is metres long, within a metre of the truth's
    travelled, truth = (float(x) for x in re.search(r"travelled ([\d.]+) m \(ground truth ([\d.]+) m\)", out).groups())
    assert truth > 5.0
    assert abs(travelled - truth) < 1.0
