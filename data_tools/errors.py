"""Errors raised for bad input files."""

from prc_slam.scan import ScanError


class DataError(ScanError):
    """An input file is missing, truncated or malformed; the message names the file."""
