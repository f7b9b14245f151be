"""ROS-free contour-error estimation and its truth."""
