"""ROS-free CDR, MCAP bags, replay timing, analysis, plots."""
