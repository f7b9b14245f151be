"""Toolpath input, redundancy resolution, feed optimization, interpolation (issue [3/7])."""
