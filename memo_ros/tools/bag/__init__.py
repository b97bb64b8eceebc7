"""Inspect, play and record rosbag2 files over DDS, byte for byte.

`memo-ros bag info|play|record`.
"""
