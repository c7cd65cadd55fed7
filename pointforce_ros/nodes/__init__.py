"""pointforce_ros.nodes."""
