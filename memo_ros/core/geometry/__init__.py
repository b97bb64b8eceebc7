"""Geometry both papers share: rotations, the body of 14 elliptic cylinders, cameras, ray casting, surfaces."""
