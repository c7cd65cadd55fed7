"""pointforce_ros.surface."""
