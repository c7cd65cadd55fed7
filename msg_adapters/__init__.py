"""ROS message <-> core type conversions. Imports message packages, never rclpy.node."""
