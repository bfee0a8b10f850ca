"""prc_slam: preregistration classification of raw LiDAR streams for odometry and mapping."""

__version__ = "0.1.0"
