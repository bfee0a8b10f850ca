"""Shared utilities: threads, forked frames, union-find, voxel grids, signals."""
