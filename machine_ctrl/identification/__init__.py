"""Identification of models from data (ROS-free core)."""
