"""rclpy-side helpers shared by nodes and tools: message conversions, QoS."""
