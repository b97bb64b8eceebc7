"""Files: camera calibrations of other tools and the studio file."""
