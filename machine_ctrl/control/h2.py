"""The H2-optimal position law of Ding's fast tool servo (seed 003_edeaa855566124b7, Ch. 6),
designed when the law is built from the axis's own models (the controllers' belief: the
drive's mass, damping and flexure, identified by `machine-ctrl identify`; hw_sim simulates the
plant's) and run as a discrete state-space filter on the position error (Fig. 6-8).

The generalized plant (Figs. 6-2, 6-3), continuous time, built by :func:`augmented_plant`:

* the stage: machine_ctrl/model/flexure_model.py (the drive's flexure: Table 5-2 as identified
  by the grey-box fit of section 5.5, machine_ctrl/experiments/fts_identify.py; current loop Eq. 5-9,
  K_T Eq. 5-10, sensor low-pass Eq. 5-8), its command through the loop delay
  tau = loop_delay + T/2 (section 4.4.4 DAC -> ADC, plus the zero-order hold's half period),
  as the (1,1) Pade approximant (1 - s tau/2)/(1 + s tau/2);
* disturbances w (unit white): the current noise through the axis's filter (Eq. 6-7 form),
  and the measurement noise at the sensor's output, one constant as Eq. (6-6) models it,
  whose density joins the sensor electronics' (``sensor_noise_density``), the per-sample
  noise and the quantization (``sensor_noise``, ``sensor_resolution``: white to the Nyquist
  frequency, one-sided density sigma sqrt(2 T));
* errors z: W_e (Eq. 6-3) on the real tool position x1 (section 6.2: "the transfer function
  matrix formed by the transfer function of each disturbance source to the tool position
  should be the cost"), in units of ``error_unit`` metres, and W_u (Eq. 6-5) on the DAC volts;
* measurement y: the sensor's output; the law sees y - x_r (no feed-forward, as the thesis).

Not in the design (stated in the README): the cutting-force weight W_fc (section 6.3.1:
"a degree of freedom to adjust the dynamic stiffness curve"; its value is not printed) and
the ground vibration W_g (Eq. 6-8; read in sensor volts, as machine_ctrl/experiments/fts_budget.py
does, it is under 1e-3 of the error budget's RMS; hw_sim simulates it, the design leaves its
states out).

A filter pole at s = 0 (the 1/s of Eq. 6-7) cannot be steered by any controller, and the
Riccati equations then have no stabilizing solution (machine_ctrl/control/h2_synthesis.py);
the design moves the noise filter's poles left by ``noise_pole`` rad/s.

The continuous controller is solved by machine_ctrl/control/h2_synthesis.py on a balanced,
normalized copy of the plant (state scaling of scipy's matrix_balance; command and
measurement scaled so that D12'D12 = D21 D21' = 1, undone afterwards), then discretized by
the bilinear (Tustin) transform at the control period. Per step, with y_k = x_k - x_r,k:
u_k = C s_k + D y_k, s_{k+1} = A s_k + B y_k.

The optimal controller may itself have an unstable pole (with the fts_lathe weights one at
+1.3 rad/s, the mirror of W_e's zero at -M_s w_b): H2 theory guarantees the closed loop
only, which is what the design checks, on the sampled loop.

No gain is live: every weight changes the whole design, so a new set is a new law.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from machine_ctrl.control.h2_synthesis import GeneralizedPlant, H2Result, H2Status, StateSpace, h2_synthesis
from machine_ctrl.control.law import Parameter, gains_change_problem, retune_checked
from machine_ctrl.model.config import AxisConfig, H2Gains
from machine_ctrl.model.flexure_model import continuous_model, held_input


@dataclass(frozen=True)
class H2Design:
    """The design of one axis: `continuous` K(s) (y -> u), `discrete` its Tustin form at
    `period`, `norm` the closed loop's H2 norm (w -> z) of the design model."""
    status: H2Status
    reason: str
    plant: GeneralizedPlant | None = None
    continuous: StateSpace | None = None
    discrete: StateSpace | None = None
    period: float = float('nan')
    norm: float = float('nan')

    @property
    def ok(self) -> bool:
        return self.status is H2Status.OK


def measurement_noise_density(axis: AxisConfig, period: float) -> float:
    """One-sided density (m/sqrt(Hz)) of the noise on the sampled position (module doc)."""
    plant = axis.plant
    electronics = 0.0 if plant.sensor_noise_density is None else plant.sensor_noise_density.density
    per_sample = plant.sensor_noise ** 2 + axis.sensor_resolution ** 2 / 12.0
    return math.sqrt(electronics ** 2 + 2.0 * per_sample * period)


def augmented_plant(axis: AxisConfig, gains: H2Gains, period: float) -> GeneralizedPlant:
    """The generalized plant of the module doc; states [stage (flexure_model order), Pade delay,
    W_e, W_u], inputs w = [current noise, measurement noise], z = [W_e x1, W_u u]; the stage's
    mechanics as the controllers know them (the drive's mass, damping and flexure)."""
    model = continuous_model(axis, belief=True)
    n, sensor, noise = model.core, model.sensor, model.current_noise     # the accelerometer is not used
    a, b_u, b_w = model.a[:n, :n], model.b_u[:n], model.b_w[:n]
    a[noise, noise] -= gains.noise_pole * np.eye(noise.stop - noise.start)
    tau = axis.plant.loop_delay + 0.5 * period
    delay, we, wu = n, n + 1, n + 2
    big = n + 3
    aa, b1, b2 = np.zeros((big, big)), np.zeros((big, 2)), np.zeros((big, 1))
    aa[:n, :n] = a
    aa[delay, delay], b2[delay, 0] = -2.0 / tau, 1.0        # Pade: u_stage = 4/tau x_d - u
    aa[:n, delay], b2[:n, 0] = 4.0 / tau * b_u[:, 0], -b_u[:, 0]
    b1[:n, 0] = b_w[:, 0]
    wb, eps, ms = gains.bandwidth, gains.epsilon, gains.peak
    scale = 1.0 / gains.error_unit
    aa[we, we], aa[we, 0] = -wb * eps, 1.0                  # W_e = 1/M_s + (w_b - w_b eps/M_s)/(s + w_b eps)
    pole, zero = gains.control_bandwidth / gains.control_epsilon, gains.control_bandwidth / gains.control_weight
    aa[wu, wu], b2[wu, 0] = -pole, 1.0                      # W_u = (1/eps_u) (1 + (zero - pole)/(s + pole))
    c1, d12 = np.zeros((2, big)), np.zeros((2, 1))
    c1[0, we], c1[0, 0] = scale * wb * (1.0 - eps / ms), scale / ms
    c1[1, wu], d12[1, 0] = (zero - pole) / gains.control_epsilon, 1.0 / gains.control_epsilon
    c2 = np.zeros((1, big))
    c2[0, 0 if sensor is None else sensor] = 1.0
    d21 = np.array([[0.0, measurement_noise_density(axis, period)]])
    return GeneralizedPlant(aa, b1, b2, c1, c2, d12, d21)


def _normalized_synthesis(p: GeneralizedPlant) -> H2Result:
    """h2_synthesis on the balanced, normalized copy of `p` (module doc), in `p`'s units."""
    _, (sc, _) = linalg.matrix_balance(p.a, permute=False, separate=True)
    inv = 1.0 / sc
    ru = 1.0 / np.sqrt(np.diag(p.d12.T @ p.d12))
    ry = 1.0 / np.sqrt(np.diag(p.d21 @ p.d21.T))
    if not (np.all(np.isfinite(ru)) and np.all(np.isfinite(ry))):
        return H2Result(H2Status.SINGULAR, 'the command needs a cost (W_u) and the measurement a noise (sensor noise)')
    q = GeneralizedPlant(inv[:, None] * p.a * sc, inv[:, None] * p.b1, inv[:, None] * p.b2 * ru,
                         p.c1 * sc, ry[:, None] * p.c2 * sc, p.d12 * ru, ry[:, None] * p.d21)
    result = h2_synthesis(q)
    if not result.ok:
        return result
    k = result.controller
    return H2Result(result.status, '', StateSpace(k.a, k.b * ry, ru[:, None] * k.c, ru[:, None] * k.d * ry),
                    result.norm)


def h2_design(axis: AxisConfig, gains: H2Gains, period: float) -> H2Design:
    """The H2 law of `axis` (module doc), or the reason there is none."""
    plant = axis.plant
    if axis.drive.type != 'voice_coil' or plant is None or plant.flexure is None or plant.current_loop is None:
        return H2Design(H2Status.INVALID_INPUT, f'axis {axis.name}: the H2 design needs a voice_coil drive '
                                                'with its flexure and current loop in the machine config')
    if axis.drive.flexure is None:
        return H2Design(H2Status.INVALID_INPUT, f'axis {axis.name}: the H2 design needs the drive\'s flexure '
                                                '(drive.flexure: the controllers\' model of the stage; '
                                                f'`machine-ctrl identify {axis.name} --out FILE` writes one)')
    if not 0.0 <= plant.loop_delay < period:
        return H2Design(H2Status.INVALID_INPUT, f'axis {axis.name}: loop_delay must be in [0, period)')
    p = augmented_plant(axis, gains, period)
    result = _normalized_synthesis(p)
    if not result.ok:
        return H2Design(result.status, f'axis {axis.name}: {result.reason}', p)
    k = _balanced(result.controller)
    from scipy import signal      # here: a servo without an h2 law need not import it (~0.8 s)
    ad, bd, cd, dd, _ = signal.cont2discrete((k.a, k.b, k.c, k.d), period, method='bilinear')
    discrete = StateSpace(ad, bd, cd, dd)
    if _sampled_loop_radius(axis, discrete, period) >= 1.0:
        return H2Design(H2Status.NO_SOLUTION, f'axis {axis.name}: the sampled loop with the discretized '
                                              'controller is unstable (a shorter control period helps)', p)
    return H2Design(H2Status.OK, '', p, k, discrete, period, result.norm)


def _balanced(k: StateSpace) -> StateSpace:
    """`k` in the state coordinates of scipy's matrix_balance (a diagonal similarity)."""
    _, (sc, _) = linalg.matrix_balance(k.a, permute=False, separate=True)
    return StateSpace(k.a * sc / sc[:, None], k.b / sc[:, None], k.c * sc, k.d)


def _sampled_loop_radius(axis: AxisConfig, k: StateSpace, period: float) -> float:
    """Spectral radius of the sampled loop as hw_sim runs it, on the design's model of the stage
    (the drive's mechanics; noise filters left out: nothing in the loop drives them)
    discretized exactly with the command of the sample at t_k applied from t_k + loop_delay,
    closed by the discrete controller `k`. An H2 controller may itself be unstable (module
    doc); its loop may not."""
    model = continuous_model(axis, belief=True)
    keep = [i for i in range(model.core) if not model.current_noise.start <= i < model.current_noise.stop]
    a, b = model.a[np.ix_(keep, keep)], model.b_u[keep]
    y = keep.index(0 if model.sensor is None else model.sensor)
    delay = axis.plant.loop_delay
    phi, gamma_new = held_input(a, b, period - delay)
    _, gamma_old = held_input(a, b, delay)
    n, nk = len(keep), k.a.shape[0]
    # states [x, u_{k-1}, controller]; u_k = C s_k + D y_k, y_k = x_k[y]
    c_y = np.zeros((1, n))
    c_y[0, y] = 1.0
    loop = np.zeros((n + 1 + nk, n + 1 + nk))
    loop[:n, :n] = phi + gamma_new @ k.d @ c_y
    loop[:n, n] = (phi @ gamma_old)[:, 0]
    loop[:n, n + 1:] = gamma_new @ k.c
    loop[n, :n], loop[n, n + 1:] = (k.d @ c_y)[0], k.c[0]
    loop[n + 1:, :n], loop[n + 1:, n + 1:] = k.b @ c_y, k.a
    return float(np.max(np.abs(np.linalg.eigvals(loop))))


class H2Controller:
    parameters = (
        Parameter('bandwidth', 'rad/s', 'w_b of W_e, Eq. (6-3)'),
        Parameter('peak', '1', 'M_s of W_e, Eqs. (6-3), (6-4)'),
        Parameter('epsilon', '1', 'eps of W_e, Eq. (6-3)'),
        Parameter('control_weight', '1', 'M_u of W_u, Eq. (6-5)'),
        Parameter('control_bandwidth', 'rad/s', 'w_bu of W_u, Eq. (6-5)'),
        Parameter('control_epsilon', '1', 'eps_u of W_u, Eq. (6-5)'),
        Parameter('error_unit', 'm', 'metres per unit of the weighted tool position error'),
        Parameter('noise_pole', 'rad/s', "the noise filters' poles move left by it (design only)"),
    )

    @classmethod
    def from_axis(cls, gains: H2Gains, axis: AxisConfig, period: float) -> H2Controller:
        design = h2_design(axis, gains, period)
        if not design.ok:
            raise ValueError(design.reason)
        return cls(gains, design)

    def __init__(self, gains: H2Gains, design: H2Design):
        self.gains, self.design = gains, design
        k = design.discrete
        self._a, self._b = k.a, k.b[:, 0].copy()
        self._c, self._d = k.c[0].copy(), float(k.d[0, 0])
        self.reset()

    def reset(self) -> None:
        self.state = np.zeros(self._a.shape[0])

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float, acc: float = 0.0) -> float:
        y = x - x_r
        u = float(self._c @ self.state) + self._d * y
        self.state = self._a @ self.state + self._b * y
        return u

    def retune_problem(self, gains: H2Gains) -> str | None:
        return gains_change_problem(self, gains)

    def retune(self, gains: H2Gains) -> None:
        retune_checked(self, gains)      # no live gain: only the same set passes
