"""The LiDAR simulator: procedural scenes, sensors, trajectories, noise, ray casting."""
