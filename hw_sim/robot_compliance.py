"""One Cartesian direction of an ABB IRB2400 face milling aluminium (Sörnmo, seed
004_33b29b0855b96c5a, Ch. 4, Figs. 4.3, 4.6): the direction z perpendicular to the feed, in
which the process force deflects the arm. The robot holds the workpiece and feeds it along
x past a fixed spindle (§4.3); z_d = 0 along the whole pass (a flat face). SI units.

Plant (per ORCA period of 4 ms, §4.3, integrated at the JR3's 8 kHz, §4.3):

* motor side, the robot's own position-controlled joint servos following the position and
  velocity references q_r, v_r that ORCA sends (§4.2):
  z_m'' = w_s^2 (q_r - z_m) + 2 zeta_s w_s (v_r - z_m'), a position loop with velocity
  feed-forward (tracks ramps without lag), natural frequency w_s (:class:`RobotConfig`);
* arm side, z_a = z_m + d + e_o(x): the deflection d of one structural mode on the motor
  side, m (z_m'' + d'') + c d' + k(x) d = f, whose static deflection is Eq. (4.1),
  f = k x_p; the stiffness k(x) = k_0 + dk sin(2 pi x / lambda) varies along the workspace
  by dk = 5 N/mm (Fig. 4.5), the modal mass m = k_0 / (2 pi 9 Hz)^2 (the eigenfrequency of
  §2.6, Fig. 2.15); e_o(x) = offset + drift x are the position errors the robot has without
  any force (the level FF cannot remove, Fig. 4.6; the calibration drift of Fig. 4.8);
* process force, Eq. (5.3) f = K_f (x_p - integral f / D_f) with x_p the feed's penetration
  into the block, x_p' = v w(x), w the engaged fraction of the tool's cutting half (0 -> 1
  over one tool radius on entry, 1 -> 0 on exit): f' = K_f v w - (K_f / D_f) f, steady
  f = D_f v (Eq. 5.4), solved exactly per 8 kHz sample; times a tooth-passing ripple
  1 + r sin(2 pi N n t) and a factor per tooth pass 1 + v g_j (g_j seeded unit Gaussian: the
  chip load varies from tooth to tooth). The force does not depend on the deflection (the
  removed depth is not fed back): an assumption of this model.

Sensors: the JR3 (8 kHz, white noise per sample; its 32 samples of a period averaged to the
250 Hz loop), the Nikon K600 (z_a + white noise, one reading per period, no latency), the
robot's motor-side position z_m (resolver: exact here). The non-force errors are in z_a, so
the tracker sees them and the motor side and the JR3 do not.

Every random draw comes from numpy generators seeded ``[seed, stream]``; with the same seed
two runs are identical to the bit whatever the control does. Integration is semi-implicit
Euler at 8 kHz: w h <= 0.016 for the fastest pole (the servo), a relative frequency error
below 1e-4.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

JR3_STREAM, TRACKER_STREAM, LOAD_TEST_STREAM, CHIP_STREAM = 0, 1, 2, 3


@dataclass(frozen=True)
class RobotConfig:
    """The robot, its servos and its sensors (module doc)."""
    stiffness: float = 150e3             # N/m, assumed: not printed. §5.5's interaction stiffness
    # for Al 7075, 143 N/mm, is the series of workpiece, tool and robot as "determined from the
    # robot position measurements" (motor side): the robot is at least that stiff, and the
    # aluminium is far stiffer than that, so the robot sits just above it: 150 N/mm. The
    # +-5 N/mm of Fig. 4.5 is then +-3 %, which the seed calls a variation "only" within +-5 N/mm.
    stiffness_variation: float = 5e3     # N/m, +-5 N/mm over the milling workspace, seed §4.4, Fig. 4.5
    stiffness_wavelength: float = 0.1    # m, assumed: one smooth period over the 100 mm pass
    eigenfrequency: float = 9.0          # Hz, the robot's eigenfrequency, seed §2.6, Fig. 2.15
    damping: float = 0.05                # assumed: 5 % of critical, a lightly damped arm mode
    servo_bandwidth: float = 20.0        # Hz, assumed: the joint servos' controlled bandwidth above
    # the 9 Hz structure (§4.2 says the structural bandwidth is the lower one)
    servo_damping: float = 0.7           # assumed: a well-damped position loop
    offset: float = 40e-6                # m, assumed: the non-force error of the robot in z. The
    # robot's frame was calibrated to the tracker's (§4.3), accurate to +-40 um: a residual of
    # that size; the seed prints no size (Fig. 4.6: "centered around different levels"). Its
    # sign, the deflection's (either is as likely), adds it to the uncompensated error
    drift: float = 0.0                   # m per m of feed: the inaccurate calibration of Fig. 4.8
    force_noise: float = 0.5             # N RMS per 8 kHz sample, assumed: a few tenths of a newton,
    # strain-gauge F/T sensor; 0.09 N after the 32-sample average
    tracker_noise: float = 20e-6         # m RMS, the K600's "+-40 um" accuracy (§4.3) read as
    # +-2 sigma of white Gaussian noise, independent per reading
    control_rate: float = 250.0          # Hz, ORCA, seed §4.3
    force_rate: float = 8000.0           # Hz, JR3, seed §4.3

    def stiffness_at(self, x):
        """k(x), N/m, at feed position(s) x (module doc)."""
        phase = 2.0 * math.pi * np.asarray(x) / self.stiffness_wavelength
        return self.stiffness + self.stiffness_variation * np.sin(phase)


@dataclass(frozen=True)
class MillingConfig:
    """The face-milling pass (module doc). The mean force normal to the feed is that of a
    full-immersion cut by the mechanistic model, N a (c K_tc / 4 + K_te / pi) (Altintas), c
    the feed per tooth: 67 N here, so D_f = 6.7 N s/mm at 10 mm/s (:attr:`removal`)."""
    interaction_stiffness: float = 143e3  # N/m, K_f for Al 7075, seed §5.5
    feed: float = 0.010                   # m/s, seed §4.4
    depth: float = 3e-3                   # m, depth of cut, seed §4.4
    tool_diameter: float = 6e-3           # m, seed §4.3
    spindle_speed: float = 24000.0        # rpm, seed §4.3
    flutes: int = 2                       # assumed: a two-flute cutter, usual for aluminium
    cutting_coefficient: float = 767e6    # N/m^2, K_tc, assumed: published for Al 7075-T6
    edge_coefficient: float = 27.7e3      # N/m, K_te, assumed: published for Al 7075-T6
    ripple: float = 0.5                   # assumed: +-50 % of the mean at tooth passing (800 Hz).
    # A zero-helix slot swings more, a helical tool less; the 9 Hz mode passes (9/800)^2 of it
    # and the JR3 average and C(s) remove the rest, so its size hardly matters
    length: float = 0.1                   # m, assumed: a 100 mm block, a pass of about 10 s
    variation: float = 0.1                # assumed: each tooth's force differs from the mean by a
    # seeded Gaussian factor of 10 % RMS (chip load varied by runout and the material), held over
    # its tooth period: broadband, it is what excites the robot's 9 Hz mode during the cut (§2.6,
    # Fig. 2.15 shows that mode in the error); the seed prints no size

    @property
    def removal(self) -> float:
        """D_f of Eq. (5.3), N s/m: the mean full-immersion force normal to the feed over the feed."""
        per_tooth = self.feed / (self.flutes * self.spindle_speed / 60.0)
        per_depth = per_tooth * self.cutting_coefficient / 4.0 + self.edge_coefficient / math.pi
        force = self.flutes * self.depth * per_depth
        return force / self.feed

    def engagement(self, x):
        """w(x): the engaged fraction of the tool's cutting half at tool-centre position x (the
        block spans 0..length; linear over one radius on entry and exit)."""
        r = self.tool_diameter / 2.0
        x = np.asarray(x, float)
        return np.clip((x + r) / r, 0.0, 1.0) * np.clip((self.length - x) / r, 0.0, 1.0)


class MillingRobot:
    """The plant of the module doc over one pass: `lead_in` seconds at rest before the tool
    touches the block, the pass, `lead_out` seconds after it leaves. Per ORCA period k (time
    k times the 4 ms period): read the sensors, then :meth:`step` with the references for the period."""

    def __init__(self, robot: RobotConfig, milling: MillingConfig, seed: int,
                 lead_in: float = 1.0, lead_out: float = 0.5):
        ratio = robot.force_rate / robot.control_rate
        if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
            raise ValueError(f'the force rate {robot.force_rate} Hz is not a multiple of the control rate '
                             f'{robot.control_rate} Hz')
        self.robot, self.milling, self.seed = robot, milling, seed
        self.substeps = int(round(ratio))
        self.period = 1.0 / robot.control_rate
        h = self.period / self.substeps
        r = milling.tool_diameter / 2.0
        pass_time = (milling.length + r) / milling.feed
        self.periods = int(math.ceil((lead_in + pass_time + lead_out) / self.period))
        samples = self.periods * self.substeps
        t = np.arange(samples) * h
        x_fine = -r + milling.feed * (t - lead_in)          # tool centre, block from 0 to length
        # Eq. (5.3) exactly per sample (engagement held over the sample)
        decay = math.exp(-h * milling.interaction_stiffness / milling.removal)
        mean = lfilter([0.0, (1.0 - decay) * milling.removal * milling.feed], [1.0, -decay],
                       milling.engagement(x_fine))
        tooth = milling.flutes * milling.spindle_speed / 60.0
        teeth = np.floor(t * tooth).astype(int)
        chips = 1.0 + milling.variation * np.random.default_rng([seed, CHIP_STREAM]).standard_normal(teeth[-1] + 1)
        force = mean * (1.0 + milling.ripple * np.sin(2.0 * math.pi * tooth * t)) * chips[teeth]
        self.force = force.reshape(self.periods, self.substeps)
        self.feed_position = x_fine[::self.substeps]        # x at each period's start
        self.cutting = milling.engagement(self.feed_position) > 0.0
        self.time = t[::self.substeps]
        jr3 = np.random.default_rng([seed, JR3_STREAM]).normal(0.0, robot.force_noise, self.force.shape)
        self._force_readings = (self.force + jr3).mean(axis=1)
        tracker = np.random.default_rng([seed, TRACKER_STREAM])
        self._tracker_noise = tracker.normal(0.0, robot.tracker_noise, self.periods)
        self._stiffness = robot.stiffness_at(self.feed_position)
        w = 2.0 * math.pi * robot.eigenfrequency
        self._mass = robot.stiffness / (w * w)
        self._damping = 2.0 * robot.damping * math.sqrt(robot.stiffness * self._mass)
        self._h = h
        self.k = 0
        self.motor = self.motor_velocity = self.deflection = self.deflection_velocity = 0.0

    # --- sensors at the start of period k -----------------------------------------------
    def force_reading(self) -> float:
        """The JR3's mean over the last period (0 before the first)."""
        return float(self._force_readings[self.k - 1]) if self.k > 0 else 0.0

    def tracker_reading(self) -> float:
        return self.arm_position() + float(self._tracker_noise[self.k])

    def motor_position(self) -> float:
        return self.motor

    def arm_position(self) -> float:
        """The true z_a (no sensor)."""
        x = float(self.feed_position[self.k])
        return self.motor + self.deflection + self.robot.offset + self.robot.drift * x

    # --- one ORCA period --------------------------------------------------------------------
    def step(self, position_reference: float, velocity_reference: float) -> None:
        """Hold q_r, v_r over period k, integrate it at 8 kHz (module doc), k += 1."""
        robot = self.robot
        h = self._h
        ws = 2.0 * math.pi * robot.servo_bandwidth
        ws2, dws = ws * ws, 2.0 * robot.servo_damping * ws
        m, c, kk = self._mass, self._damping, float(self._stiffness[self.k])
        zm, vm, d, vd = self.motor, self.motor_velocity, self.deflection, self.deflection_velocity
        for f in self.force[self.k].tolist():
            am = ws2 * (position_reference - zm) + dws * (velocity_reference - vm)
            ad = (f - c * vd - kk * d) / m - am
            vm += h * am
            zm += h * vm
            vd += h * ad
            d += h * vd
        self.motor, self.motor_velocity, self.deflection, self.deflection_velocity = zm, vm, d, vd
        self.k += 1

    # --- the stiffness identification of §4.2 ------------------------------------------------
    def measure_stiffness(self, positions, load: float, readings: int) -> np.ndarray:
        """§4.2, Eq. (4.1): at each position a static `load` (N) is applied; the stiffness is the
        JR3's mean force over the tracker's mean deflection (loaded minus unloaded, `readings`
        readings each; JR3 averaged over as many 8 kHz samples per reading). N/m per position."""
        robot = self.robot
        rng = np.random.default_rng([self.seed, LOAD_TEST_STREAM])
        positions = np.asarray(positions, float)
        n = len(positions)
        samples = readings * self.substeps
        force = load + rng.normal(0.0, robot.force_noise, (n, samples)).mean(axis=1)
        unloaded = rng.normal(0.0, robot.tracker_noise, (n, readings)).mean(axis=1)
        loaded = load / robot.stiffness_at(positions) + rng.normal(0.0, robot.tracker_noise, (n, readings)).mean(axis=1)
        return force / (loaded - unloaded)
