"""Work on plain threads (prc_slam.util.threads): chunks cover every item once, steps come back in
order with their seconds, errors are raised in the caller, and the online detector's outputs are
the same with one thread as with several."""

from __future__ import annotations

import itertools

import numba
import numpy as np
import pytest

from prc_slam.util.threads import in_threads, side_by_side


@pytest.fixture(params=[1, 2])
def threads(request):
    old = numba.get_num_threads()
    numba.set_num_threads(min(request.param, numba.config.NUMBA_NUM_THREADS))
    yield numba.get_num_threads()
    numba.set_num_threads(old)


@pytest.mark.parametrize("n", [0, 1, 255, 256, 513, 2048])
def test_in_threads_covers_every_item_once(threads, n):
    seen = np.zeros(n, np.int64)
    chunks = []

    def work(lo, hi):
        chunks.append((lo, hi))
        seen[lo:hi] += 1

    in_threads(work, n, min_chunk=256)
    assert (seen == 1).all()
    k = max(1, min(threads, n // 256))  # threads used; each takes four chunks' worth on average
    assert len(chunks) == (1 if k == 1 else 4 * k)
    c = sorted(chunks)  # contiguous pieces of 0..n
    assert c[0][0] == 0 and c[-1][1] == n and all(a[1] == b[0] for a, b in itertools.pairwise(c))


def test_errors_reach_the_caller(threads):
    def work(lo, hi):
        if lo > 0 or threads == 1:
            raise ValueError("bad chunk")

    with pytest.raises(ValueError, match="bad chunk"):
        in_threads(work, 1024, min_chunk=256)
    with pytest.raises(KeyError):
        side_by_side(lambda: {}["missing"], lambda: 1)
    with pytest.raises(ZeroDivisionError):
        side_by_side(lambda: 1, lambda: 1 / 0)


def test_steps_side_by_side_in_order_with_their_seconds(threads):
    out, sec = side_by_side(lambda: 1, lambda: np.arange(3), lambda: "c")
    assert out[0] == 1 and out[2] == "c" and list(out[1]) == [0, 1, 2]
    assert len(sec) == 3 and min(sec) >= 0


def test_detector_outputs_do_not_depend_on_threads(hdl64_scans):
    from prc_slam.online import OnlineDetector

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba may use one thread only (NUMBA_NUM_THREADS): no threaded run to compare")

    out = {}
    old = numba.get_num_threads()
    try:
        for t in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(t)
            det = OnlineDetector()
            out[t] = [det.process(s) for s in hdl64_scans]
    finally:
        numba.set_num_threads(old)
    a, b = out.values()
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.labels, y.labels)
        np.testing.assert_array_equal(x.car_instances, y.car_instances)
        assert x.car_boxes == y.car_boxes
        assert len(x.curb_polylines) == len(y.curb_polylines)
        for p, q in zip(x.curb_polylines, y.curb_polylines, strict=True):
            np.testing.assert_array_equal(p, q)


@pytest.fixture(scope="module")
def hdl64_scans():
    from data_tools.sim.simulator import SimConfig, Simulator
    from prc_slam.scan import Scan

    sim = Simulator(SimConfig(scene="urban", sensor="hdl64", frames=3))
    return [Scan(sim.frame(i).ranges, sim.sensor.model) for i in range(3)]
