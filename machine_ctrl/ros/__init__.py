"""The ROS side: message conversion and the thin nodes."""
