"""Readers, writers and (later) the LiDAR simulator for prc_slam."""

from data_tools.datasets import Dataset, open_dataset
from data_tools.errors import DataError

__all__ = ["DataError", "Dataset", "open_dataset"]
