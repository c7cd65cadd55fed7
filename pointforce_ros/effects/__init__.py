"""pointforce_ros.effects."""
