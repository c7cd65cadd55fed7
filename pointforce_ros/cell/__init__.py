"""pointforce_ros.cell."""
