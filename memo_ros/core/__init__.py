"""ROS-free science: body model, cameras, rendering, gait, segmentation, filters."""
