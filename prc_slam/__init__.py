"""prc_slam: preregistration classification of raw LiDAR streams for odometry and mapping."""

__version__ = "0.1.0"


def _choose_numba_threading_layer() -> None:
    """numba's default tries TBB first and warns when the TBB it finds (pulled in by other
    packages) is too old: take OpenMP when numba has it, else its own work queue."""
    import os

    if "NUMBA_THREADING_LAYER" in os.environ:
        return
    from numba import config

    try:
        from numba.np.ufunc import omppool  # noqa: F401

        config.THREADING_LAYER = "omp"
    except ImportError:
        config.THREADING_LAYER = "workqueue"


_choose_numba_threading_layer()
