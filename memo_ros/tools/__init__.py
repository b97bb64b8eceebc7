"""The `memo-ros` command line tools (third layer: built on core and rclpy)."""
