"""Rerun visualisation: the sink the pipeline feeds (algorithms never log)."""

from prc_slam.viz.sink import RerunSink, VizConfig

__all__ = ["RerunSink", "VizConfig"]
