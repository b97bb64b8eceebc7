"""Geometry both papers share.

Rotations, the body of 14 elliptic cylinders, cameras, ray casting, surfaces.
"""
