"""Folders of sweeps: sweeps of several Ouster sensors in one folder are warned."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest


def test_a_folder_of_sweeps_from_several_ouster_sensors_is_warned(ouster_files, tmp_path, caplog):
    """A folder of sweeps of several Ouster sensors (OS-0, OS-1, OS-2) is warned when opened, as one sequence of
    them has frame times going back."""
    import shutil

    from data_tools.formats.ouster import OusterSequence

    def one(prefix: str) -> Path:
        found = [f for f in ouster_files if f.name.startswith(prefix)]
        if not found:
            pytest.skip(f"no shared Ouster sweep {prefix}*")
        return found[0]

    same, mixed = tmp_path / "same", tmp_path / "mixed"
    for folder, prefixes in (
        (same, ["OS-1-128_lb_n3_frame0", "OS-1-128_lb_n3_frame1"]),
        (mixed, ["OS-1-128_lb_n3_frame0", "OS-2-128"]),
    ):
        folder.mkdir()
        for k, prefix in enumerate(prefixes):
            shutil.copy(one(prefix), folder / f"{k:06d}.npz")
    with caplog.at_level(logging.WARNING, logger="prc_slam.readers"):
        seq = OusterSequence(same)
        [seq[i] for i in range(len(seq))]
        assert not caplog.records
        seq = OusterSequence(mixed)
        [seq[i] for i in range(len(seq))]
        seq[1]
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and "000001.npz: its beam table" in warned[0] and "mixes sensors" in warned[0]
