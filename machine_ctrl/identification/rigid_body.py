"""A feed drive's rigid-body model and its friction curve from recorded motion (Yuen thesis
section 4.2.1-4.2.2: the least-squares rigid-body model, Eqs. 4.1 and 4.15-4.18, and the Stribeck curve
of the friction, Eq. 4.41). Plain numeric functions on arrays (no ROS, no simulator):
machine_ctrl/experiments/identify.py makes the runs and calls them.

**Rigid body** (:func:`fit_rigid_body`). The drive's force F = K u (K = K_a K_t, the
amplifier and motor constants of the data sheet, drive.gain) moves the mass m against
viscous and Coulomb friction:

    F = m a + b v + F_c+ [v > 0] - F_c- [v < 0]                    (Eqs. 4.1, 4.8; asymmetric F_c)

Position, force and the direction indicators [v > 0], [v < 0] are low-passed by the same
zero-phase filter, so the equation holds for the filtered signals (the filter is linear; a
reversal's Coulomb step, smeared by it, is smeared alike on both sides). Velocity and
acceleration are central differences of the filtered position. Samples slower than
`min_speed` are left out: the Stribeck region and the presliding bristles, where F_c is not
the friction. m, b, F_c+,
F_c- come from linear least squares (numpy.linalg.lstsq). Each comes with a 95 % interval,
t(0.975, N - 4) times its standard error from the residual variance. The residual of filtered
data is not white, so the interval is narrower than the truth. It says how well the data
pins the value down; it is not a guarantee.

**Friction along the stroke.** A guideway's friction varies with position (thesis section
4.2.3). Left out, it biases b: the multisine's speed and position are not independent. With
candidate wavelengths, F_c± [v ≷ 0] gets the terms (s± sin kx + c± cos kx) [v ≷ 0],
k = 2 pi / wavelength. These are linear for a given k, so each candidate is one least-squares
solve. The wavelength with the smallest residual is kept if its residual energy is below
VARIATION_GAIN of the fit's without it; only wavelengths within the span of positions seen
are tried.

**Stribeck curve and viscous friction** (:func:`fit_steady_friction`): the steady force
against constant speeds, both directions at once,

    |F(v)| = s g(v) + b |v|,  g(v) = F_s e^{-|v|/w1} + F_c (1 - e^{-|v|/w2})    (Eq. 4.41)

with s the friction's variation along the stroke averaged over the run (from the rigid-body
fit). The fit is scipy.optimize.least_squares on log-spaced speeds, in relative terms (each
point weighted by 1/|F|), with the parameters positive. b comes from here and not from the
multisine: the viscous force is under 1 % of the Coulomb level at 5 mm/s and 6-9 % at 0.1 m/s
(x_c), and a fit
over constant speeds sees it without the multisine's errors.

Results carry a status and a one-line reason; data that cannot give an answer is refused,
never patched.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.identification.status import FitStatus

# assumed: 50 Hz. The filter passes the rigid-body band of the excitation (machine_ctrl/
# experiments/identify.py: up to 8 Hz) untouched and takes out the encoder's count noise
# (40 nm at 10 kHz is 16 m/s^2 of acceleration unfiltered).
FILTER_HZ = 50.0
MIN_SAMPLES = 1000
# assumed: a variation along the stroke is taken into the model when it removes a third of the
# residual's energy (the position terms always remove some: four more columns)
VARIATION_GAIN = 2.0 / 3.0


@dataclass(frozen=True)
class Estimate:
    value: float
    half_width: float            # of the 95 % interval (module docstring); nan where none

    def within(self, true: float, relative: float) -> bool:
        return abs(self.value - true) <= relative * abs(true)


@dataclass(frozen=True)
class FrictionVariation:
    """The friction's level along the stroke, 1 + A sin(2 pi x / wavelength + phase) per
    direction (positive, negative): the rigid-body fit sees it on F_c, and it scales the
    whole curve g(v) (the plant's variation, and the steady and presliding fits' use of it)."""
    wavelength: float                         # m
    amplitude: tuple[float, float]            # A, relative to the direction's Coulomb level
    phase: tuple[float, float]                # rad, at x = 0


@dataclass(frozen=True)
class RigidBodyFit:
    status: FitStatus
    reason: str = ''
    mass: Estimate | None = None              # kg (kg m^2)
    viscous: Estimate | None = None           # N s/m (N m s/rad)
    coulomb: tuple[Estimate, Estimate] | None = None   # N (N m), (positive, negative) direction
    samples: int = 0                          # the samples used (faster than min_speed)
    residual_rms: float = math.nan            # N (N m)
    variation: FrictionVariation | None = None   # along the stroke, where asked for and found


@dataclass(frozen=True)
class StribeckFit:
    status: FitStatus
    reason: str = ''
    static: float = math.nan                  # F_s, N
    coulomb: float = math.nan                 # F_c, N
    omega1: float = math.nan                  # w1, m/s
    omega2: float = math.nan                  # w2, m/s
    worst_relative_residual: float = math.nan


def lowpass(signal: np.ndarray, period: float, cutoff: float = FILTER_HZ) -> np.ndarray:
    """Zero-phase 4th-order Butterworth low-pass (scipy.signal.sosfiltfilt)."""
    from scipy.signal import butter, sosfiltfilt
    sos = butter(4, cutoff, fs=1.0 / period, output='sos')
    return sosfiltfilt(sos, signal)


def fit_rigid_body(force, position, period: float, min_speed: float, variation_wavelengths=None) -> RigidBodyFit:
    """m, b, F_c+, F_c- from the force applied over each step and the position at each step
    (same length), module docstring; with `variation_wavelengths` (m), also the friction's
    variation along the stroke at the best of them."""
    force, position = np.asarray(force, float), np.asarray(position, float)
    if force.shape != position.shape or force.ndim != 1:
        return RigidBodyFit(FitStatus.REFUSED, f'force and position must be equally long 1-D series, got '
                                               f'{force.shape} and {position.shape}')
    if len(force) < MIN_SAMPLES:
        return RigidBodyFit(FitStatus.REFUSED, f'{len(force)} samples: at least {MIN_SAMPLES} needed')
    if not (np.isfinite(force).all() and np.isfinite(position).all()):
        return RigidBodyFit(FitStatus.REFUSED, 'the data holds NaN or inf')
    x, f = lowpass(position, period), lowpass(force, period)
    v = np.gradient(x, period)
    a = np.gradient(v, period)
    edge = int(round(5.0 / (FILTER_HZ * period)))          # the filter's start-up at both ends: 5 / f_c
    use = np.zeros(len(x), bool)
    use[edge:len(x) - edge] = True
    use &= np.abs(v) > min_speed
    if use.sum() < MIN_SAMPLES or not (v[use] > 0).any() or not (v[use] < 0).any():
        return RigidBodyFit(FitStatus.REFUSED, f'{int(use.sum())} samples faster than {min_speed:g} m/s, not '
                                               f'both directions: the excitation does not move the axis enough')
    forward, backward = (v > 0).astype(float), -(v < 0).astype(float)
    base = [a, v, lowpass(forward, period), lowpass(backward, period)]
    y = f[use]

    def solve(wavelength):
        """(theta, residual, regressors) with the friction's variation at `wavelength` (None: none)."""
        columns = list(base)
        if wavelength is not None:
            k = 2 * math.pi / wavelength
            columns += [lowpass(d * w(k * x), period) for d in (forward, backward) for w in (np.sin, np.cos)]
        regressors = np.column_stack([c[use] for c in columns])
        theta, _, rank, _ = np.linalg.lstsq(regressors, y, rcond=None)
        return theta, y - regressors @ theta, regressors, rank

    theta, residual, regressors, rank = solve(None)
    if rank < 4:
        return RigidBodyFit(FitStatus.REFUSED, 'the regressors are dependent (acceleration, velocity and direction '
                                               'do not vary independently): excite with several frequencies')
    variation = None
    if variation_wavelengths is not None:
        span = float(np.ptp(x[use]))
        candidates = [w for w in variation_wavelengths if w <= span]          # at least one period seen
        if candidates:
            costs = [float(r @ r) for r in (solve(w)[1] for w in candidates)]
            best = candidates[int(np.argmin(costs))]
            if costs[int(np.argmin(costs))] < VARIATION_GAIN * float(residual @ residual):
                variation = best
                theta, residual, regressors, rank = solve(best)
    dof = len(y) - regressors.shape[1]
    variance = residual @ residual / dof
    from scipy.stats import t
    half = t.ppf(0.975, dof) * np.sqrt(variance * np.diag(np.linalg.inv(regressors.T @ regressors)))
    m, b, cp, cn = (Estimate(float(value), float(h)) for value, h in zip(theta[:4], half[:4]))
    along = None
    if variation is not None:          # per direction: amplitude relative to its level, phase at x = 0
        sp, cp_, sn, cn_ = theta[4:]
        along = FrictionVariation(variation, (math.hypot(sp, cp_) / cp.value, math.hypot(sn, cn_) / cn.value),
                                  (math.atan2(cp_, sp), math.atan2(cn_, sn)))
    return RigidBodyFit(FitStatus.OK, '', m, b, (cp, cn), int(use.sum()), float(math.sqrt(variance)), along)


def stribeck(speed, static: float, coulomb: float, omega1: float, omega2: float):
    """g(|v|), Eq. (4.41)."""
    speed = np.abs(np.asarray(speed, float))
    return static * np.exp(-speed / omega1) + coulomb * (1.0 - np.exp(-speed / omega2))


@dataclass(frozen=True)
class SteadyFrictionFit:
    status: FitStatus
    reason: str = ''
    viscous: float = math.nan                 # b, N s/m, shared by both directions
    curves: tuple[StribeckFit, StribeckFit] | None = None   # (positive, negative) direction
    bristle_time: float = math.nan            # tau, s, where slopes were given (fit_steady_friction)


def fit_steady_friction(speeds, forces, scales=None, slopes=None) -> SteadyFrictionFit:
    """The steady force against constant speed, both directions at once:

        |F(v)| = s g(v) + b |v| +- tau s' |v| g(v)    (g: Eq. 4.41 per direction, b shared)

    `speeds` (m/s, > 0) and `forces` (N, magnitudes) as (2, n) arrays for the positive and the
    negative direction; `scales`: the mean of the friction's variation along the stroke over
    each run (1 where None); `slopes`: the mean of its derivative ds/dx over each run, 1/m. With
    slopes, the bristles' damping is fitted too: sliding over a friction that varies along the
    stroke, the LuGre bristle deflection z = s g/sigma0 follows s(x), and sigma1 dz/dt adds
    tau s' v g (tau = sigma1/sigma0; + in the positive direction, - in the negative). It is in
    proportion to v, like b v, and would be taken for it (x_c: 0.2 N at 0.1 m/s, 7 % of b v).
    The fitted tau also takes up the bristles' lag behind s(x) (a force g g'/sigma0, not in
    proportion to v): it keeps b right, and it is not an identification of sigma1/sigma0.
    At least 5 speeds spanning two decades per direction."""
    speeds, forces = np.abs(np.asarray(speeds, float)), np.asarray(forces, float)
    scales = np.ones_like(forces) if scales is None else np.asarray(scales, float)
    bristles = slopes is not None
    slopes = np.zeros_like(forces) if slopes is None else np.asarray(slopes, float)
    if speeds.ndim != 2 or speeds.shape[0] != 2 or not speeds.shape == forces.shape == scales.shape == slopes.shape:
        return SteadyFrictionFit(FitStatus.REFUSED, f'speeds, forces and scales must be (2, n) arrays, got '
                                                    f'{speeds.shape}, {forces.shape}, {scales.shape}')
    if speeds.shape[1] < 5:
        return SteadyFrictionFit(FitStatus.REFUSED, f'{speeds.shape[1]} speeds: at least 5 needed per direction')
    if not all(np.isfinite(a).all() and (a > 0).all() for a in (speeds, forces, scales)) or not np.isfinite(slopes).all():
        return SteadyFrictionFit(FitStatus.REFUSED, 'speeds, forces and scales must be finite and > 0')
    if (speeds.max(axis=1) < 100 * speeds.min(axis=1)).any():
        return SteadyFrictionFit(FitStatus.REFUSED, f'speeds {speeds.min():g}-{speeds.max():g} m/s: two decades '
                                                    f'needed to see both the static and the Coulomb level')
    from scipy.optimize import least_squares
    middle = [float(np.sqrt(s.min() * s.max())) for s in speeds]
    start = np.log([p for d in range(2) for p in (forces[d].min(), forces[d].max(), middle[d], middle[d])]
                   + [max(1e-9, 0.01 * forces.max() / speeds.max())] + ([1e-4] if bristles else []))
    direction = np.array([1.0, -1.0])

    def model(p):
        q = np.exp(p)
        tau = q[9] if bristles else 0.0
        return np.array([(scales[d] + direction[d] * tau * slopes[d] * speeds[d]) * stribeck(speeds[d], *q[4 * d:4 * d + 4])
                         + q[8] * speeds[d] for d in range(2)])

    def relative(p):
        return (model(p) / forces - 1.0).ravel()
    with np.errstate(over='ignore', divide='ignore', invalid='ignore'):
        solution = least_squares(relative, start, method='trf', bounds=(start - 12.0, start + 12.0))
    if not solution.success or not np.isfinite(solution.fun).all():
        return SteadyFrictionFit(FitStatus.REFUSED, f'the curve fit did not converge: {solution.message}')
    q = np.exp(solution.x)
    worst = np.abs(solution.fun.reshape(2, -1)).max(axis=1)
    curves = tuple(StribeckFit(FitStatus.OK, '', *(float(v) for v in q[4 * d:4 * d + 4]), float(worst[d]))
                   for d in range(2))
    return SteadyFrictionFit(FitStatus.OK, '', float(q[8]), curves, float(q[9]) if bristles else math.nan)


@dataclass(frozen=True)
class LuGreCurve:
    """The symmetric g(v) = F_c + (F_s - F_c) exp(-|v|/Omega_s) of the LuGre feed-forward (thesis
    Eq. 4.59 as corrected in seed-notes.md)."""
    static: float                  # F_s, N, Eq. (4.60)
    coulomb: float                 # F_c, N, Eq. (4.61)
    stribeck_velocity: float       # Omega_s, m/s, least squares (Eq. 4.45)


def lugre_curve(steady: SteadyFrictionFit, speeds) -> LuGreCurve:
    """The feed-forward's curve from the two identified directions of `steady` (status OK): F_s
    and F_c the means of the directions' levels (Eqs. 4.60, 4.61), and Omega_s minimizing the
    squared difference (Eq. 4.45) to the mean of the two directions' curves (Eq. 4.41) at
    `speeds` (m/s, > 0), searched on a log scale over their span widened by a factor e at each
    end."""
    from scipy.optimize import minimize_scalar
    positive, negative = steady.curves
    static = 0.5 * (positive.static + negative.static)
    coulomb = 0.5 * (positive.coulomb + negative.coulomb)
    speeds = np.abs(np.asarray(speeds, float))
    mean = 0.5 * sum(stribeck(speeds, c.static, c.coulomb, c.omega1, c.omega2) for c in (positive, negative))

    def cost(log_omega):            # Eq. (4.59) is Eq. (4.41) with omega1 = omega2 = Omega_s
        omega = math.exp(log_omega)
        return float(np.sum((stribeck(speeds, static, coulomb, omega, omega) - mean) ** 2))
    low, high = math.log(speeds.min()) - 1.0, math.log(speeds.max()) + 1.0
    best = minimize_scalar(cost, bounds=(low, high), method='bounded', options={'xatol': 1e-6})
    return LuGreCurve(static, coulomb, math.exp(best.x))
