"""Shared test check: sampled axis positions, differenced at the control period (what a
servo sees), stay within the machine's velocity, acceleration and jerk limits."""
import numpy as np


def assert_within_limits(machine, positions, tolerance=1.001):
    t = machine.control_period
    for order, name in ((1, 'velocity'), (2, 'acceleration'), (3, 'jerk')):
        limit = np.array([getattr(a.limits, name) for a in machine.axes])
        peak = np.abs(np.diff(positions, order, axis=0)).max(axis=0) / t**order
        assert (peak <= tolerance * limit).all(), f'{name}: peak / limit {peak / limit}'
