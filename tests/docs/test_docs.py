"""The documentation site builds with ``mkdocs build --strict`` (broken links, missing anchors and
docstring warnings fail it) and its API page carries the main classes with their docstrings."""

from __future__ import annotations

import html
import inspect
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MKDOCS = ROOT / ".venv" / "bin" / "mkdocs"


def page_text(path: Path) -> str:
    """The visible text of an HTML page, whitespace collapsed."""
    return page_text_of(path.read_text())


def first_sentence(obj: object) -> str:
    doc = inspect.getdoc(obj) or ""
    return re.sub(r"\s+", " ", doc.split("\n\n")[0]).strip()


def test_page_text_strips_markup():
    assert page_text_of("<p>A <code>Pipeline</code>&amp;\n more</p><script>x()</script>") == "A Pipeline & more"


def page_text_of(markup: str) -> str:
    """The visible text of HTML markup: tags, scripts and styles dropped, entities decoded."""
    raw = re.sub(r"<(script|style)\b.*?</\1>", " ", markup, flags=re.S)
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", raw))).strip()


@pytest.mark.skipif(shutil.which(str(MKDOCS)) is None, reason="mkdocs not installed (make setup installs it)")
def test_docs_build_strict_with_the_api_reference(tmp_path):
    from prc_slam import Pipeline, PRCConfig, PRCKissICP, Preprocessor

    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    res = subprocess.run(
        [str(MKDOCS), "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-4000:]
    for page in ("index", "inputs", "commands", "api", "architecture", "RESULTS"):
        assert (site / page / "index.html").is_file() or (site / f"{page}.html").is_file(), page
    api = page_text(site / "api" / "index.html")
    for cls in (Pipeline, Preprocessor, PRCKissICP, PRCConfig):
        assert cls.__name__ in api
        sentence = first_sentence(cls)
        assert sentence, f"{cls.__name__} has no docstring"
        # the docstring's first words as rendered (markup such as ``code`` is stripped by the renderer)
        words = re.sub(r"[`*]", "", sentence).split()[:6]
        assert " ".join(words) in api, f"{cls.__name__}: {' '.join(words)!r} not on the API page"
