"""The README's Python examples run as written: test functions under pytest (in a fresh directory,
first writing their golden files, then checking against them), everything else in one namespace."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def python_blocks() -> list[str]:
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_readme_has_the_library_examples():
    blocks = python_blocks()
    joined = "\n".join(blocks)
    for name in ("Preprocessor", "PRCKissICP", "trajectory_regression", "Pipeline"):
        assert name in joined


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
    assert "travelled" in out and "ground recall" in out
