"""The image front end: encodings, change detection (Rohr eq. 1), cleanup, backgrounds, contours, edges."""
