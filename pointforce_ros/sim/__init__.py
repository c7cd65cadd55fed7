"""pointforce_ros.sim."""
