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

_EXPORTS = {
    "Config": "prc_slam.config",
    "PRCConfig": "prc_slam.prc.config",
    "Scan": "prc_slam.scan",
    "SpinningSensor": "prc_slam.scan",
    "ProfilerSensor": "prc_slam.scan",
    "Pipeline": "prc_slam.pipeline",
    "PipelineFrame": "prc_slam.pipeline",
    "Preprocessor": "prc_slam.preprocess",
    "PRCKissICP": "prc_slam.preprocess",
    "OnlineDetector": "prc_slam.online",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    """The public API, imported on first use (``from prc_slam import Pipeline, Preprocessor``)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'prc_slam' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
