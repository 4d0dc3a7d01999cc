"""Mapping: SLAM, scan matching, loop closure, frontiers and map quality."""
