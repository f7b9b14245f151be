"""Plant models against closed-form solutions."""
import dataclasses
import math
import random

import numpy as np
import pytest

from hw_sim.plant import FrictionAxis, LinearAxis, Sensor, quantize
from machine_ctrl.control.lugre import StribeckCurve


def table_axis(micromill, name='x_f', **plant):
    axis = micromill.axis(name)
    return dataclasses.replace(axis, plant=dataclasses.replace(axis.plant, force_noise=0.0, **plant))


def test_rigid_table_axis_is_exact_under_constant_force(micromill):
    axis = table_axis(micromill)
    plant = LinearAxis(axis, 1e-4, random.Random(0))
    u = plant.apply(10.0)                           # command units, as quantized by the DAC
    accel = u * axis.drive.gain / axis.plant.mass   # N / kg, the true mass
    for _ in range(1000):
        plant.step(u)
    t = 0.1
    assert plant.position == pytest.approx(0.5 * accel * t * t, rel=1e-9)
    assert plant.velocity == pytest.approx(accel * t, rel=1e-9)


def test_flexible_table_axis_has_unit_dc_gain_and_its_modes(micromill):
    """z_f: the force filter has DC gain 1, so after the mode rings out the acceleration is
    gain*u/m; its frequency response has the configured resonance/anti-resonance."""
    axis = table_axis(micromill, 'z_f')
    plant = LinearAxis(axis, 1e-4, random.Random(0))
    u = plant.apply(5.0)
    velocities = []
    for _ in range(2000):
        plant.step(u)
        velocities.append(plant.velocity)
    accel = (velocities[-1] - velocities[-1001]) / 0.1
    assert accel == pytest.approx(u * axis.drive.gain / axis.plant.mass, rel=1e-3)


def test_command_saturation_and_quantization(micromill):
    axis = micromill.axis('x_c')
    plant = FrictionAxis(axis, 1e-4, 2, random.Random(0))
    assert plant.apply(7.0) == 5.0 and plant.apply(-9.0) == -5.0           # +-5 V, thesis 4.2.2
    assert plant.apply(0.0374) == pytest.approx(0.025)                       # 0.025 V steps
    assert plant.apply(0.0376) == pytest.approx(0.05)


@pytest.mark.parametrize('u', [1.5, -1.5])
def test_sliding_friction_is_the_stribeck_curve(micromill, u):
    """Once the bristles have settled, LuGre friction is g(v) + b v (thesis Eq. 4.41): the
    axis accelerates with m dv/dt = F - g(v) - b v."""
    axis = micromill.axis('x_c')
    friction = dataclasses.replace(axis.plant.friction, variation=0.0)
    axis = dataclasses.replace(axis, plant=dataclasses.replace(axis.plant, friction=friction))
    plant = FrictionAxis(axis, 1e-4, 2, random.Random(0))
    for _ in range(3000):
        plant.step(u)
    v0 = plant.velocity
    plant.step(u)
    accel = (plant.velocity - v0) / 1e-4
    curve = StribeckCurve(friction.static, friction.coulomb, friction.omega1, friction.omega2)
    v = 0.5 * (v0 + plant.velocity)
    assert abs(v) > 0.01
    expected = u * axis.drive.gain - math.copysign(curve(v), v) - axis.plant.damping * v
    assert axis.plant.mass * accel == pytest.approx(expected, rel=1e-3)


def test_friction_varies_along_the_stroke(micromill):
    plant = FrictionAxis(micromill.axis('x_c'), 1e-4, 2, random.Random(0))
    scales = [plant.friction_scale(x) for x in np.linspace(-0.05, 0.05, 200)]
    assert min(scales) == pytest.approx(0.85, abs=1e-3) and max(scales) == pytest.approx(1.15, abs=1e-3)


def test_sensor_quantizes_and_differentiates():
    sensor = Sensor(40e-9, 0.0, 1e-4, random.Random(0))
    assert sensor.measure(1.01e-6) == pytest.approx((1.0e-6, 1.0e-6 / 1e-4))
    position, velocity = sensor.measure(1.03e-6)
    assert position == pytest.approx(1.04e-6) and velocity == pytest.approx(0.04e-6 / 1e-4)
    assert quantize(-0.01, 40e-9) == pytest.approx(-0.01, abs=1e-15)


def test_halving_the_friction_substep_changes_the_motion_by_under_1_percent(micromill):
    """Open loop, a force that reverses the axis: 2 vs 4 substeps per period."""
    axis = micromill.axis('x_c')
    t = np.arange(20000) * 1e-4
    commands = 1.2 * np.sin(2 * math.pi * 1.0 * t)             # V, +-54 N: slides and reverses
    paths = []
    for substeps in (2, 4):
        plant = FrictionAxis(axis, 1e-4, substeps, random.Random(0))
        path = []
        for u in commands:
            plant.step(u)
            path.append(plant.position)
        paths.append(np.array(path))
    travel = np.ptp(paths[1])
    assert travel > 1e-3
    assert np.abs(paths[0] - paths[1]).max() < 0.01 * travel
