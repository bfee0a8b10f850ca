"""The peer tools (Open3D SOR/ROR, Patchwork++) behind prc_slam.evaluation.peers: masks in input order."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prc_slam.evaluation import peers


def test_ror_hand_computed():
    # 0 and 0.3 are each other's only neighbour within 0.5 m; 10.0, 10.1, 10.2 have two each; 5 has none
    pts = np.array([[0, 0, 0], [0.3, 0, 0], [5, 0, 0], [10, 0, 0], [10.1, 0, 0], [10.2, 0, 0]], float)
    assert peers.radius_outlier_keep(pts, radius=0.5, min_points=1).tolist() == [1, 1, 0, 1, 1, 1]
    assert peers.radius_outlier_keep(pts, radius=0.5, min_points=2).tolist() == [0, 0, 0, 1, 1, 1]
    assert not peers.radius_outlier_keep(pts, radius=0.5, min_points=3).any()


def test_sor_drops_the_isolated_point():
    rng = np.random.default_rng(0)
    cluster = rng.normal(0, 0.05, (200, 3))
    pts = np.vstack([cluster[:100], [[5.0, 5.0, 5.0]], cluster[100:]])
    keep = peers.statistical_outlier_keep(pts, nb_neighbors=10, std_ratio=2.0)
    assert keep.shape == (201,)
    assert not keep[100]
    assert keep[:100].mean() > 0.9 and keep[101:].mean() > 0.9


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_open3d_masks_follow_input_order(seed):
    """Permuting the input permutes the masks: indices map back to the input exactly."""
    rng = np.random.default_rng(seed)
    pts = np.vstack([rng.uniform(-2, 2, (60, 3)), rng.normal(0, 0.1, (60, 3))])
    perm = rng.permutation(len(pts))
    for fn in (
        lambda p: peers.radius_outlier_keep(p, radius=0.5, min_points=2),
        lambda p: peers.statistical_outlier_keep(p, nb_neighbors=8, std_ratio=1.0),
    ):
        assert np.array_equal(fn(pts)[perm], fn(pts[perm]))


def test_empty_and_bad_input():
    empty = np.zeros((0, 3))
    assert peers.radius_outlier_keep(empty).shape == (0,)
    assert peers.statistical_outlier_keep(empty).shape == (0,)
    with pytest.raises(ValueError, match="non-finite"):
        peers.radius_outlier_keep(np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(ValueError, match="shape"):
        peers.statistical_outlier_keep(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="radius"):
        peers.radius_outlier_keep(np.zeros((4, 3)), radius=0.0)


def _street(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A flat ground, 1.7 m below the sensor with two boxes and a wall; truth: ground mask."""
    g = rng.uniform(-30, 30, (20000, 2))
    g = g[np.hypot(g[:, 0], g[:, 1]) > 3.0]
    ground = np.column_stack([g, -1.7 + rng.normal(0, 0.01, len(g))])
    box = np.column_stack([rng.uniform(5, 9, 3000), rng.uniform(2, 4, 3000), rng.uniform(-1.6, 0.0, 3000)])
    wall = np.column_stack([rng.uniform(-20, 20, 3000), np.full(3000, 12.0), rng.uniform(-1.6, 4.0, 3000)])
    pts = np.vstack([ground, box, wall]).astype(np.float32)
    truth = np.r_[np.ones(len(ground), bool), np.zeros(6000, bool)]
    return pts, truth


def test_patchwork_ground_on_a_simulated_street():
    pytest.importorskip("pypatchworkpp", reason="Patchwork++ is an optional peer: pip install prc-slam[peers]")
    rng = np.random.default_rng(1)
    pts, truth = _street(rng)
    perm = rng.permutation(len(pts))
    pts, truth = pts[perm], truth[perm]
    ground = peers.patchwork_ground(pts, sensor_height=1.7)
    assert ground.shape == truth.shape and ground.dtype == bool
    # inside Patchwork++'s range (2.7-80 m) the flat ground is found and the boxes and wall are not
    precision = (ground & truth).sum() / ground.sum()
    recall = (ground & truth).sum() / truth.sum()
    assert precision > 0.98 and recall > 0.9, (precision, recall)


def test_patchwork_reports_every_point_once_and_in_order():
    pytest.importorskip("pypatchworkpp", reason="Patchwork++ is an optional peer: pip install prc-slam[peers]")
    rng = np.random.default_rng(2)
    pts, _ = _street(rng)
    a = peers.patchwork_ground(pts, sensor_height=1.7)
    perm = rng.permutation(len(pts))
    b = peers.patchwork_ground(pts[perm], sensor_height=1.7)
    # Patchwork++ fits planes per bin; the order of points in a bin barely matters
    assert (a[perm] == b).mean() > 0.995
    with pytest.raises(ValueError, match="unknown Patchwork"):
        peers.PatchworkGround(no_such_parameter=1)
    with pytest.raises(ValueError, match="intensity"):
        peers.PatchworkGround(sensor_height=1.7)(pts, intensity=np.ones(3))


def test_missing_package_raises_peer_unavailable(monkeypatch):
    monkeypatch.setitem(sys.modules, "pypatchworkpp", None)
    with pytest.raises(peers.PeerUnavailable, match="pip install"):
        peers.patchwork_ground(np.zeros((5, 3)))
    monkeypatch.setitem(sys.modules, "open3d", None)
    with pytest.raises(peers.PeerUnavailable, match="pip install"):
        peers.radius_outlier_keep(np.zeros((5, 3)))
