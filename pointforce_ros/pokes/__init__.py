"""pointforce_ros.pokes."""
