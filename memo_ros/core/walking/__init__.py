"""Rohr's MEMO walker.

Gait model, model contours, similarity, position, search, Kalman filter, tracker.
"""
