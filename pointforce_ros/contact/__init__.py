"""pointforce_ros.contact."""
