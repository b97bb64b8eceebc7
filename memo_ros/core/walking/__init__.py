"""Rohr's MEMO walker: gait model, model contours, similarity, position, search, Kalman filter, tracker."""
