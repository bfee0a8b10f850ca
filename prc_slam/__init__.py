"""prc_slam: preregistration classification of raw LiDAR streams for odometry and mapping."""

__version__ = "0.1.0"


def _choose_numba_threading_layer() -> None:
    """numba's default tries TBB first and warns when the TBB it finds (pulled in by other
    packages) is too old: take OpenMP when numba has it, else its own work queue. Set through
    ``NUMBA_THREADING_LAYER`` before numba is imported, without importing it (importing the
    package stays cheap, so the command line can take Ctrl-C cleanly while it loads)."""
    import os
    from importlib.util import find_spec
    from pathlib import Path

    if "NUMBA_THREADING_LAYER" in os.environ:
        return
    spec = find_spec("numba")
    roots = [] if spec is None or spec.submodule_search_locations is None else spec.submodule_search_locations
    has_omp = any(any((Path(r) / "np" / "ufunc").glob("omppool*")) for r in roots)
    os.environ["NUMBA_THREADING_LAYER"] = "omp" if has_omp else "workqueue"


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
