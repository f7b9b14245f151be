"""ROS-free experiments of the seeds, run offline."""
