"""The feed direction of Sörnmo's machining robot cutting a material whose removal varies
(seed 004_33b29b0855b96c5a, Ch. 5): the robot's velocity response to ORCA's velocity
reference, and the machining force of Eq. (5.3). SI units.

Robot (per 4 ms ORCA period, integrated at the JR3's 8 kHz): the joint servos' closed loop
along the feed, the motor side of hw_sim/robot_compliance.py with its RobotConfig,

    x'' = w_s^2 (q_r - x) + 2 zeta_s w_s (v_r - x'),   q_r' = v_r

(ORCA sends the velocity reference v_r, held over the period, and its integral q_r, ramping
with it). The
arm's compliance is not a state of its own here: §5.5 reads K_f as the interaction stiffness
of workpiece, tool and robot "as determined from the robot position measurements", so the
penetration rate of Eq. (5.3) is the robot's measured feed velocity v = x'.

Force, Eq. (5.9) with a time-varying removal parameter D_f(t) (Fig. 5.3: a varying depth of
cut): f' = K_f v - (K_f / D_f) f, solved exactly per 8 kHz sample with v held,
f <- a f + (1 - a) D_f v, a = exp(-K_f h / D_f). The force is a contact force: it does not
go below zero (a tool backing out of the cut loses contact; assumed, the seed's linear model
says nothing of it).

Sensors per period: the JR3's mean over the period's 32 samples, white noise per sample
(RobotConfig.force_noise); the feed velocity as the mean over the period from the robot's
position measurement, plus white noise (:attr:`FeedProcess.velocity_noise`). Every random
draw comes from numpy generators seeded ``[seed, stream]``: two runs with one seed are equal
to the bit whatever the control does.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hw_sim.robot_compliance import JR3_STREAM, RobotConfig

VELOCITY_STREAM = 4
# assumed: 10 um/s RMS per 4 ms reading: the robot's motor resolvers (~0.06 um at the tool,
# config/machines/robot_piezo.yaml) differentiated over a period give ~15 um/s of
# quantization; white noise of that size stands for it (and gives the identification the
# noise covariance its Kalman filter needs)
VELOCITY_NOISE = 1e-5     # m/s


@dataclass(frozen=True)
class RemovalProfile:
    """D_f(t), N s/m, piecewise linear through `points` ((t, D_f), t ascending; a repeated
    time is a step: the later value holds from it on). Constant before the first point and
    after the last."""
    points: tuple[tuple[float, float], ...]

    def __post_init__(self):
        if not self.points:
            raise ValueError('a removal profile needs at least one point')
        times = [t for t, _ in self.points]
        if any(b < a for a, b in zip(times, times[1:])):
            raise ValueError(f'removal profile times must not decrease, got {times}')
        if not all(math.isfinite(d) and d > 0 for _, d in self.points):
            raise ValueError(f'D_f must be positive and finite, got {[d for _, d in self.points]}')

    def at(self, t: float) -> float:
        points = self.points
        if t < points[0][0]:
            return points[0][1]
        for (t0, d0), (t1, d1) in zip(points, points[1:]):
            if t0 <= t < t1:
                return d0 + (d1 - d0) * (t - t0) / (t1 - t0)
        return points[-1][1]


class FeedProcess:
    """The plant of the module doc in a material of interaction stiffness `stiffness` (K_f,
    N/m) and removal `removal` (a RemovalProfile), the tool in contact from t = 0. Per ORCA
    period k (time k times the 4 ms period): read :meth:`force_reading` and :meth:`velocity_reading`, then
    :meth:`step` with v_r for the period. `removal` None: no material (the identification
    runs in the air: f = 0, the JR3 reads its noise)."""

    def __init__(self, robot: RobotConfig, stiffness: float, removal: RemovalProfile | None, seed: int,
                 velocity_noise: float = VELOCITY_NOISE):
        ratio = robot.force_rate / robot.control_rate
        if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
            raise ValueError(f'the force rate {robot.force_rate} Hz is not a multiple of the control rate '
                             f'{robot.control_rate} Hz')
        if not (math.isfinite(stiffness) and stiffness > 0):
            raise ValueError(f'interaction stiffness must be positive, got {stiffness!r}')
        self.robot, self.stiffness, self.removal = robot, float(stiffness), removal
        self.substeps = int(round(ratio))
        self.period = 1.0 / robot.control_rate
        self._h = self.period / self.substeps
        self.velocity_noise = velocity_noise
        self._jr3 = np.random.default_rng([seed, JR3_STREAM])
        self._speed = np.random.default_rng([seed, VELOCITY_STREAM])
        self.k = 0
        self.position = self.velocity = self.reference = self.force = 0.0
        self._force_mean = 0.0        # the true force's mean over the last period
        self._velocity_mean = 0.0     # the true feed velocity's mean over the last period
        self._force_reading = self._velocity_reading = 0.0

    @property
    def time(self) -> float:
        return self.k * self.period

    def removal_now(self) -> float:
        """D_f at the start of period k (N s/m); nan without material."""
        return self.removal.at(self.time) if self.removal is not None else math.nan

    # --- sensors at the start of period k -----------------------------------------------
    def force_reading(self) -> float:
        """The JR3's mean over the last period (0 before the first), N."""
        return self._force_reading

    def velocity_reading(self) -> float:
        """The feed velocity over the last period, measured (0 before the first), m/s."""
        return self._velocity_reading

    def true_force(self) -> float:
        """The force's true mean over the last period, N (no sensor)."""
        return self._force_mean

    # --- one ORCA period --------------------------------------------------------------------
    def step(self, velocity_reference: float) -> None:
        """Hold v_r over period k (its integral q_r ramps with it), integrate at 8 kHz (module doc),
        k += 1."""
        robot, h = self.robot, self._h
        ws = 2.0 * math.pi * robot.servo_bandwidth
        ws2, dws = ws * ws, 2.0 * robot.servo_damping * ws
        decay = removal = 0.0
        if self.removal is not None:
            removal = self.removal_now()
            decay = math.exp(-h * self.stiffness / removal)
        x, v, q, f = self.position, self.velocity, self.reference, self.force
        start, forces = x, 0.0
        for _ in range(self.substeps):
            a = ws2 * (q - x) + dws * (velocity_reference - v)
            v += h * a
            x += h * v
            q += h * velocity_reference
            if self.removal is not None:
                f = max(0.0, decay * f + (1.0 - decay) * removal * v)
            forces += f
        self.position, self.velocity, self.reference, self.force = x, v, q, f
        self._force_mean = forces / self.substeps
        self._velocity_mean = (x - start) / self.period
        noise = self._jr3.normal(0.0, robot.force_noise, self.substeps).mean()
        self._force_reading = self._force_mean + float(noise) if self.removal is not None else float(noise)
        self._velocity_reading = self._velocity_mean + float(self._speed.normal(0.0, self.velocity_noise))
        self.k += 1
