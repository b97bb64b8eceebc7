"""The image front end.

Encodings, change detection (Rohr eq. 1), cleanup, backgrounds, contours, edges.
"""
