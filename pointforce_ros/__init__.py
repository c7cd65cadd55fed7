"""pointforce_ros: learned point-wise force response of soft objects, served over ROS 2.

The core (everything outside :mod:`pointforce_ros.nodes`) is plain Python on numpy, scipy,
scikit-learn and Open3D and never imports ``rclpy``.
"""

__version__ = '0.1.0'
