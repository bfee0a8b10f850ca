"""Errors in configuration files name the file and the key as written."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("prc:\n  k: 99\n  bogus_key: 3\n", "bad.yaml: prc.bogus_key: Extra inputs are not permitted (got 3)"),
        ("prc:\n  k: many\n", "bad.yaml: prc.k: Input should be a valid integer"),
        ("mapclass:\n  ground:\n    cell: x\n", "bad.yaml: mapclass.ground.cell: Input should be a valid number"),
        ("prcc:\n  k: 99\n", "bad.yaml: prcc: Extra inputs are not permitted"),
        ("prc: [1, 2\n", "bad.yaml: cannot read config (line 2, column 1): expected ',' or ']'"),
    ],
    ids=["unknown key", "wrong type", "nested wrong type", "unknown section", "broken yaml"],
)
def test_config_errors_name_the_file_and_the_key_as_written(tmp_path, text, expected):
    """Unknown keys and sections and values of the wrong type name the configuration file and the key as written
    in it (underscores, not an option's hyphens); broken YAML gives the parser's message with its line and
    column. Both in ``Config.from_yaml`` and on the command line."""
    from typer.testing import CliRunner

    from prc_slam.cli import app
    from prc_slam.config import Config

    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError) as info:
        Config.from_yaml(path, Config())
    assert str(info.value).startswith(str(path)) and expected.split("bad.yaml: ")[1] in str(info.value)
    res = CliRunner().invoke(app, ["mapclass", str(tmp_path / "none.npy"), "--config", str(path)])
    assert res.exit_code == 2 and expected in " ".join(res.output.split())
