"""Odometry: the KISS-ICP adapter (and, later, class-aware registration)."""

from prc_slam.odometry.kiss import KissOdometry, OdometryConfig

__all__ = ["KissOdometry", "OdometryConfig"]
