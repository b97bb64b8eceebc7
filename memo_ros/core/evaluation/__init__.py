"""Scoring tracks: joint errors against truth, silhouette overlap without it."""
