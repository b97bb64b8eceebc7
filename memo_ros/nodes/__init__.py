"""Thin rclpy nodes wrapping memo_ros.core: parameters, QoS, conversions, diagnostics."""
