"""Plant models of one axis each, stepped once per control period with a zero-order-held
command. Scalar Python floats on purpose (PiezoDriveAxis aside: its stage is numpy): for a handful of axes this is several times
cheaper than numpy on tiny arrays, and results do not depend on how axes are grouped.

* :class:`FrictionAxis` — linear-motor axis (Yuen thesis Eqs. 4.1/4.46): m a = K_a K_t u
  - b v - F_f, with LuGre friction F_f = sigma0 eps + sigma1 d eps/dt (Eqs. 4.58, 4.62)
  whose steady state is the asymmetric Stribeck curve of Eq. (4.41), its magnitude varying
  along the stroke. Integrated with `substeps` semi-implicit Euler steps per period (the
  bristle deflection by its exact exponential for the frozen velocity, so it never
  overshoots); the substep count is chosen so that doubling it changes results < 1 %
  (test/test_plant.py; circle statistics: README "Simulation").
* :class:`LinearAxis` — any linear axis: the free-floating maglev table (Eqs. 4.69-4.72) with
  an optional lightly damped resonance / anti-resonance pair (the flexibility the notch
  filters of Table 4.4 were designed against), or a voltage-normalized servo drive
  (Sencer Table 1). Exact zero-order-hold discretization.
* :class:`PositionServoAxis` — a drive closing its own position loop (a robot joint), and
  :class:`PiezoDriveAxis` — a piezo stage given by its modes (hw_sim/piezo_stage.py).
* :class:`Sensor` — encoder / probe: additive Gaussian noise, quantization to the
  resolution, velocity by differentiating the quantized position (thesis Eq. 4.34).

Command path for every axis: saturation to +-command_limit, then quantization to
command_resolution (thesis section 4.2.2), then the actuator gain (force and voltage
drives; a position_servo or piezo drive takes the command as its position).
"""
from __future__ import annotations

import math
import random

import numpy as np

from hw_sim.piezo_stage import PiezoAxis, PiezoAxisModel
from machine_ctrl.control.lugre import StribeckCurve, bristle_rate
from machine_ctrl.model import modal
from machine_ctrl.model.config import AxisConfig


def quantize(value: float, step: float) -> float:
    return step * math.floor(value / step + 0.5) if step > 0.0 else value


class _Actuator:
    def __init__(self, axis: AxisConfig, rng: random.Random):
        drive = axis.drive
        self.limit, self.resolution, self.gain = drive.command_limit, drive.command_resolution, drive.gain
        self.force_noise, self.rng = axis.plant.force_noise, rng

    def disturbance(self) -> float:
        """Actuator force noise for this period, in command units."""
        return self.rng.gauss(0.0, self.force_noise) / self.gain if self.force_noise > 0.0 else 0.0

    def apply(self, u: float) -> float:
        """The command the amplifier actually produces: saturated, then quantized."""
        return quantize(min(self.limit, max(-self.limit, u)), self.resolution)

    @property
    def sensed(self) -> float:
        """What the position sensor sees (before its noise and quantization)."""
        return self.position


class FrictionAxis(_Actuator):
    def __init__(self, axis: AxisConfig, period: float, substeps: int, rng: random.Random,
                 position: float = 0.0):
        super().__init__(axis, rng)
        friction = axis.plant.friction
        self.mass, self.viscous = axis.plant.mass, axis.plant.damping     # the truth (drive: the belief)
        self.curve = StribeckCurve(friction.static, friction.coulomb, friction.omega1, friction.omega2)
        self.sigma0, self.sigma1 = friction.sigma0, friction.sigma1
        self.variation = friction.variation
        self.wavenumber = 2.0 * math.pi / friction.variation_wavelength
        self.h = period / substeps
        self.substeps = substeps
        self.position, self.velocity, self.eps = position, 0.0, 0.0

    def friction_scale(self, x: float) -> float:
        """Friction magnitude relative to Table 4.2 at position x (assumed sinusoidal)."""
        return 1.0 + self.variation * math.sin(self.wavenumber * x)

    def step(self, u: float) -> float:
        applied = self.apply(u)
        force = self.gain * (applied + self.disturbance())
        h, m, b, s0, s1 = self.h, self.mass, self.viscous, self.sigma0, self.sigma1
        scale = self.friction_scale(self.position)      # varies on a cm scale: once per period
        x, v, eps = self.position, self.velocity, self.eps
        for _ in range(self.substeps):
            g = scale * self.curve(v)
            rate = bristle_rate(v, eps, s0, g)
            v += h * (force - s0 * eps - s1 * rate - b * v) / m
            x += h * v
            decay = s0 * abs(v) / g
            if decay > 0.0:                              # exact for frozen v: eps -> g sgn(v)/s0
                target = v / decay
                eps = target + (eps - target) * math.exp(-decay * h)
        self.position, self.velocity, self.eps = x, v, eps
        return applied


class _HeldAxis(_Actuator):
    """A linear drive x' = a x + b u stepped by its exact zero-order hold; state [x, v] or
    [x, v, w, dw], unrolled by hand (the per-step cost of every drive of this kind)."""

    def _hold(self, a, bvec, period: float, position: float) -> None:
        """The exact zero-order-hold discretization of x' = a x + bvec u, at rest at `position`."""
        n = len(bvec)
        phi, gamma = modal.held(a, bvec, period)
        self._a = phi.ravel().tolist()
        self._b = gamma.tolist()
        self._state = (position,) + (0.0,) * (n - 1)
        self._propagate = self._propagate2 if n == 2 else self._propagate4

    @property
    def position(self) -> float:
        return self._state[0]

    @property
    def velocity(self) -> float:
        return self._state[1]

    def _propagate2(self, u: float):
        x, v = self._state
        a, b = self._a, self._b
        return a[0] * x + a[1] * v + b[0] * u, a[2] * x + a[3] * v + b[1] * u

    def _propagate4(self, u: float):
        x, v, w, dw = self._state
        a, b = self._a, self._b
        return (a[0] * x + a[1] * v + a[2] * w + a[3] * dw + b[0] * u,
                a[4] * x + a[5] * v + a[6] * w + a[7] * dw + b[1] * u,
                a[8] * x + a[9] * v + a[10] * w + a[11] * dw + b[2] * u,
                a[12] * x + a[13] * v + a[14] * w + a[15] * dw + b[3] * u)

    def step(self, u: float) -> float:
        applied = self.apply(u)
        self._state = self._propagate(applied + self.disturbance())
        return applied


class LinearAxis(_HeldAxis):
    """x = G(s) u with G(s) = gain F(s) / (m s^2 + b s) and the flexible part
    F(s) = (w_r^2/w_z^2) (s^2 + 2 z_z w_z s + w_z^2) / (s^2 + 2 z_r w_r s + w_r^2), DC gain 1.
    State [x, v] or [x, v, w, dw] (w: force-filter state)."""

    def __init__(self, axis: AxisConfig, period: float, rng: random.Random, position: float = 0.0):
        super().__init__(axis, rng)
        plant = axis.plant
        m, b = plant.mass, plant.damping      # the truth (drive: the belief)
        if plant.resonance is None:
            a = np.array([[0.0, 1.0], [0.0, -b / m]])
            bvec = np.array([0.0, self.gain / m])
        else:
            wr, zr = plant.resonance.omega, plant.resonance.zeta
            wz, zz = plant.antiresonance.omega, plant.antiresonance.zeta
            k = wr * wr / (wz * wz)
            # effective force f = k (w'' + 2 zz wz w' + wz^2 w), with w'' = gain u - 2 zr wr w' - wr^2 w
            c_w, c_dw, c_u = k * (wz * wz - wr * wr), k * 2.0 * (zz * wz - zr * wr), k
            a = np.array([[0.0, 1.0, 0.0, 0.0],
                          [0.0, -b / m, c_w / m, c_dw / m],
                          [0.0, 0.0, 0.0, 1.0],
                          [0.0, 0.0, -wr * wr, -2.0 * zr * wr]])
            bvec = np.array([0.0, c_u * self.gain / m, 0.0, self.gain])
        self._hold(a, bvec, period, position)


class PositionServoAxis(_HeldAxis):
    """A drive whose own controller closes the position loop (drive type position_servo: an
    industrial robot's joint, Sörnmo section 2.4, "controlled by a conventional robot
    controller"): x'' = w^2 (u - x) - 2 zeta w x' with u the position reference
    (plant.servo), exact zero-order hold."""

    def __init__(self, axis: AxisConfig, period: float, rng: random.Random, position: float = 0.0):
        super().__init__(axis, rng)
        w, zeta = axis.plant.servo.omega, axis.plant.servo.zeta
        self._hold(np.array([[0.0, 1.0], [-w * w, -2.0 * zeta * w]]), np.array([0.0, w * w]), period, position)


class PiezoDriveAxis(_Actuator):
    """A piezo drive (drive type piezo): the stage of hw_sim/piezo_stage.py with the machine's
    modes, its command saturated and quantized like every drive's."""

    def __init__(self, axis: AxisConfig, period: float, rng: random.Random, position: float = 0.0):
        super().__init__(axis, rng)
        self.stage = PiezoAxis(PiezoAxisModel.from_axis(axis), period, None, position)

    @property
    def position(self) -> float:
        return self.stage.position

    @property
    def velocity(self) -> float:
        return self.stage.velocity

    def step(self, u: float) -> float:
        applied = self.apply(u)
        self.stage.step(applied)
        return applied


class Sensor:
    """Measured position = quantize(sensed + noise); velocity = backward difference / period.
    `sensed` is the plant's sensor output: its true position unless the plant models the
    sensor's dynamics (hw_sim/flexure.py)."""

    def __init__(self, resolution: float, noise: float, period: float, rng: random.Random,
                 position: float = 0.0):
        self.resolution, self.noise, self.period, self.rng = resolution, noise, period, rng
        self.last = quantize(position, resolution)

    def measure(self, sensed: float) -> tuple[float, float]:
        noisy = sensed + (self.rng.gauss(0.0, self.noise) if self.noise > 0.0 else 0.0)
        position = quantize(noisy, self.resolution)
        velocity = (position - self.last) / self.period
        self.last = position
        return position, velocity
