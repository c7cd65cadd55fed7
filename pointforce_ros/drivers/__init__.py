"""pointforce_ros.drivers."""
