"""``classify --preset auto`` (the default): the PRC preset the input's sensor calls for.

The paper's parameters on a 64-beam spinning sensor (KITTI 00 frames 0-2) give ground F1 0.63 and
call 9.2 % of the solid classes noise, where ``--preset multibeam`` gives 0.96 and 0.9 %.
"""

from __future__ import annotations

import dataclasses
import json

import pytest
from typer.testing import CliRunner

from prc_slam.cli import app
from prc_slam.prc.config import PRCConfig

runner = CliRunner()
MULTIBEAM_SAID = (
    "PRC preset multibeam: the sweeps are from a 64-beam spinning sensor (--preset paper or multibeam to choose)"
)


def _sensor(name: str):
    from data_tools.sim.simulator import SimConfig, Simulator

    return Simulator(SimConfig(scene="urban", sensor=name, frames=1)).sensor.model


@pytest.mark.parametrize("mode", ["urban", "forest"])
def test_spinning_multi_beam_sensors_take_multibeam_in_their_mode(mode):
    for name in ("hdl64", "vlp16"):
        cfg, why = PRCConfig.for_sensor(_sensor(name), mode)
        assert cfg == PRCConfig.named("multibeam", mode) and cfg.mode == mode
        assert cfg.adaptive and cfg.ground == "auto"
        assert why.startswith("multibeam") and f"{len(_sensor(name).altitude)}-beam" in why


def test_profilers_and_unknown_sensors_keep_the_papers_parameters():
    cfg, why = PRCConfig.for_sensor(_sensor("profiler-urban"), "urban")
    assert cfg == PRCConfig.preset("urban") and not cfg.adaptive and why.startswith("paper (urban)")
    cfg, _ = PRCConfig.for_sensor(None, "forest")
    assert cfg == PRCConfig.preset("forest")
    hdl64 = _sensor("hdl64")
    one_beam = dataclasses.replace(
        hdl64, altitude=hdl64.altitude[:1], beam_azimuth=hdl64.beam_azimuth[:1], column_shift=hdl64.column_shift[:1]
    )
    cfg, why = PRCConfig.for_sensor(one_beam, "urban")
    assert cfg == PRCConfig.preset("urban") and "one beam" in why


def test_named_presets_and_adaptive_override():
    assert PRCConfig.named("paper", "forest") == PRCConfig.preset("forest")
    assert PRCConfig.named("multibeam", "forest").mode == "forest"
    assert PRCConfig.named("multibeam", "urban", adaptive=False).adaptive is False
    with pytest.raises(ValueError, match="unknown preset 'auto'"):
        PRCConfig.named("auto")


def test_classify_defaults_to_the_sensors_preset_on_real_kitti(kitti_dir, tmp_path):
    """The default run on KITTI 00 frames 0-2 is the multibeam one (said on the log), with its
    ground and noise figures; ``--preset paper`` still runs the paper's parameters."""
    out = {}
    for args in ([], ["--preset", "paper"]):
        path = tmp_path / f"m{len(args)}.json"
        res = runner.invoke(app, ["classify", str(kitti_dir), "--max-frames", "3", "--json", str(path), *args])
        assert res.exit_code == 0, res.output
        out[bool(args)] = json.loads(path.read_text())
        said = [line for line in res.output.splitlines() if "PRC preset" in line]
        assert said == ([] if args else [MULTIBEAM_SAID]), res.output
    auto, paper = out[False], out[True]
    assert auto["config"] == PRCConfig.named("multibeam").model_dump(mode="json")
    assert paper["config"] == PRCConfig.preset("urban").model_dump(mode="json")
    assert auto["per_class"]["ground"]["f1"] >= 0.95 > paper["per_class"]["ground"]["f1"]
    assert auto["noise_in_solid_classes"] <= 0.02
