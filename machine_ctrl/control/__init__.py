"""ROS-free control laws behind one interface."""
