"""NumPy clouds: more columns, named fields or an npz are read; arrays that are not clouds are one-line
errors; an Ouster npz is still a sweep.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.inputs.las import ground_and_wall


def _numpy_variants(xyz: np.ndarray) -> dict[str, object]:
    n = len(xyz)
    rng = np.random.default_rng(3)
    structured = np.zeros(n, [("x", "<f8"), ("intensity", "<f4"), ("y", "<f8"), ("z", "<f8")])
    structured["x"], structured["y"], structured["z"] = xyz.T
    return {
        "n4.npy": np.column_stack([xyz, rng.random(n)]),
        "n6.npy": np.column_stack([xyz, np.tile([0.0, 0.0, 1.0], (n, 1))]),
        "structured.npy": structured,
        "alone.npz": {"anything": xyz},
        "named.npz": {"points": np.column_stack([xyz, rng.random(n)]), "intensity": rng.random(n)},
    }


@pytest.mark.parametrize("name", ["n4.npy", "n6.npy", "structured.npy", "alone.npz", "named.npz"])
def test_numpy_clouds_with_more_columns_fields_or_in_an_npz_are_read(tmp_path, name):
    """``(N, 4)`` / ``(N, 6)`` arrays, structured arrays with x, y, z fields and an ``.npz`` holding a cloud are
    read as clouds (the npz is not taken for an Ouster sweep)."""
    from data_tools.formats.clouds import cloud_chunks, cloud_size, is_cloud_file

    xyz, _ = ground_and_wall(500)
    value = _numpy_variants(xyz)[name]
    path = tmp_path / name
    if isinstance(value, dict):
        np.savez(path, **value)
    else:
        np.save(path, value)
    assert is_cloud_file(path) and cloud_size(path) == len(xyz)
    np.testing.assert_array_equal(np.concatenate(list(cloud_chunks(path, chunk=200))), xyz)


@pytest.mark.parametrize(
    ("name", "value", "needle"),
    [
        ("rows.npy", np.zeros((3, 50)), "looks like x, y, z rows"),
        ("col.npy", np.zeros((50, 1)), "expected (N, 3)"),
        ("text.npy", np.array(["a", "b"]), "numeric"),
        ("fields.npy", np.zeros(5, [("a", "f4"), ("b", "f4")]), "x, y, z fields"),
        ("two.npz", {"a": np.zeros((5, 3)), "b": np.zeros((5, 3))}, "which array holds the points"),
    ],
)
def test_numpy_arrays_that_are_not_clouds_are_one_line_errors(tmp_path, name, value, needle):
    from data_tools.errors import DataError
    from data_tools.formats.clouds import cloud_chunks

    path = tmp_path / name
    np.savez(path, **value) if isinstance(value, dict) else np.save(path, value)
    with pytest.raises(DataError) as err:
        list(cloud_chunks(path))
    assert needle in str(err.value) and str(err.value).count(str(path)) == 1 and "\n" not in str(err.value)


def test_an_ouster_npz_is_still_a_sweep_and_not_a_cloud(ouster_files):
    from data_tools.formats.clouds import is_cloud_file

    assert not is_cloud_file(ouster_files[0])
