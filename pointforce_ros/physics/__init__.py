"""pointforce_ros.physics."""
