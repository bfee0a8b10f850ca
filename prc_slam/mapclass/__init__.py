"""Classification after registration of the map and segregation into sub-clouds (paper 004)."""

from prc_slam.mapclass.accumulate import MapCloud, accumulate, to_world
from prc_slam.mapclass.classify import MapClassConfig, MapResult, classify_map, paper_config

__all__ = ["MapClassConfig", "MapCloud", "MapResult", "accumulate", "classify_map", "paper_config", "to_world"]
