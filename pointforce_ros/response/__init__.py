"""pointforce_ros.response."""
