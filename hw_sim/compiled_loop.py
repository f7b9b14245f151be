"""The offline runner's loop compiled (numba): the same per-step arithmetic as the plant,
sensor, servo and coupling objects the nodes use, in the same order, so a run gives the
same numbers bit for bit (test/test_compiled_loop.py compares both loops; test_determinism
compares the graph with the offline runner). Issue [5/8]: the Python loop makes ~60 calls
of small methods per step on the micromill; compiled, a step is a few microseconds.

What it covers (:func:`pack` returns None for anything else, and the Python loop runs):

* plants: :class:`~hw_sim.plant.FrictionAxis` and :class:`~hw_sim.plant.LinearAxis`
  (its exact zero-order hold, 2 or 4 states); no accelerometer;
* sensors: :class:`~hw_sim.plant.Sensor`; the noise streams go on where the
  ``random.Random`` objects stand (hw_sim/python_random.py);
* laws: sliding mode and P-PI (each + the LuGre friction feed-forward), lead-lag (its
  chain of biquads); feed-forward on or off for the whole run;
* the dual-stage coupling of coarse/fine pairs (not a Cartesian one);
* faults: a non-finite command or a stroke violation stops the machine as
  :meth:`MachineSimulator.step` does (held, efforts zero), the laws keep stepping. A
  sensed position that is not finite (an axis without a stroke run away) ends the run
  with a ValueError, where the Python loop's quantization raises too (OverflowError).

Not covered: contour control, external forces, the other plants and laws. The objects are
read when packed and not written back: the runner builds them for one run.

Every expression below is written as in its Python twin (same operations, same order; no
fast-math, and the machine code has no fused multiply-add), so both round alike; the twin
is named in each function's docstring. "Bit for bit" holds for every finite value; a NaN
(only in commands at and after a non-finite-command fault) may carry another sign or
payload, as the compiler may swap the operands of + and *.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from hw_sim import python_random
from hw_sim.plant import FrictionAxis, LinearAxis, Sensor
from hw_sim.simulator import MachineSimulator
from machine_ctrl.control.dual_stage import DualStageCoupling
from machine_ctrl.control.lead_lag import LeadLagController
from machine_ctrl.control.lugre import LuGreFeedforward, StribeckCurve
from machine_ctrl.control.ppi import PPIController
from machine_ctrl.control.servo import AxisServo, ServoGroup
from machine_ctrl.control.sliding_mode import SlidingModeController

_CACHE = True          # numba's on-disk cache (as in trajectory/resolved_rate.py)

FRICTION, HELD = 0, 1                     # plant kinds
SLIDING_MODE, FILTERS, PPI = 0, 1, 2       # law kinds
NON_FINITE, STROKE, RUN_AWAY = 1, 2, 3     # fault kinds (RUN_AWAY: a sensed position not finite)
MAX_SECTIONS = 8                          # biquads per law


@njit(cache=_CACHE)
def _quantize(value, step):
    """hw_sim.plant.quantize."""
    return step * np.floor(value / step + 0.5) if step > 0.0 else value     # a float: no int64 wrap


@njit(cache=_CACHE)
def _clamp(lo, hi, value):
    """min(hi, max(lo, value)) with Python's builtins (the first argument kept on ties)."""
    value = value if value > lo else lo
    return value if value < hi else hi


@njit(cache=_CACHE)
def _stribeck(c, v):
    """StribeckCurve.__call__; c: static (+, -), coulomb (+, -), omega1 (+, -), omega2 (+, -)."""
    i = 0 if v >= 0.0 else 1
    speed = abs(v)
    return c[i] * math.exp(-speed / c[4 + i]) + c[2 + i] * (1.0 - math.exp(-speed / c[6 + i]))


@njit(cache=_CACHE)
def _friction_step(p, curve, state, force):
    """FrictionAxis.step after the force; p: mass, viscous, sigma0, sigma1, variation,
    wavenumber, h, substeps; state: x, v, eps."""
    m, b, s0, s1, h = p[0], p[1], p[2], p[3], p[6]
    scale = 1.0 + p[4] * math.sin(p[5] * state[0])
    x, v, eps = state[0], state[1], state[2]
    for _ in range(int(p[7])):
        g = scale * _stribeck(curve, v)
        rate = v - s0 * abs(v) * eps / g
        v += h * (force - s0 * eps - s1 * rate - b * v) / m
        x += h * v
        decay = s0 * abs(v) / g
        if decay > 0.0:
            target = v / decay
            eps = target + (eps - target) * math.exp(-decay * h)
    state[0], state[1], state[2] = x, v, eps


@njit(cache=_CACHE)
def _held_step(a, b, n, state, u):
    """_HeldAxis._propagate2 / _propagate4."""
    if n == 2:
        x, v = state[0], state[1]
        state[0], state[1] = a[0] * x + a[1] * v + b[0] * u, a[2] * x + a[3] * v + b[1] * u
    else:
        x, v, w, dw = state[0], state[1], state[2], state[3]
        state[0] = a[0] * x + a[1] * v + a[2] * w + a[3] * dw + b[0] * u
        state[1] = a[4] * x + a[5] * v + a[6] * w + a[7] * dw + b[1] * u
        state[2] = a[8] * x + a[9] * v + a[10] * w + a[11] * dw + b[2] * u
        state[3] = a[12] * x + a[13] * v + a[14] * w + a[15] * dw + b[3] * u


@njit(cache=_CACHE)
def _sliding_mode(p, state, x_r, v_r, a_r, x, v):
    """SlidingModeController.step; p: lambda, K_s, rho, d-, d+, m_e, b_e, T; state: d_hat."""
    lam, k_s = p[0], p[1]
    velocity_error = v_r - v
    sigma = velocity_error + lam * (x_r - x)
    d_hat = state[0]
    u = p[5] * (lam * velocity_error + a_r) + p[6] * v + d_hat + k_s * sigma
    if not ((d_hat <= p[3] and sigma <= 0.0) or (d_hat >= p[4] and sigma >= 0.0)):
        state[0] = d_hat + p[2] * sigma * p[7]
    return u


@njit(cache=_CACHE)
def _ppi(p, state, x_r, x, v):
    """PPIController.step; p: K_p, K_v, K_vi, T; state: the integral."""
    velocity_error = p[0] * (x_r - x) - v
    state[0] += velocity_error * p[3]
    return p[1] * velocity_error + p[2] * state[0]


@njit(cache=_CACHE)
def _filters(sections, states, count, y):
    """LeadLagController.step after the error: Biquad.step of each section in turn."""
    for i in range(count):
        b0, b1, b2, a1, a2 = sections[i, 0], sections[i, 1], sections[i, 2], sections[i, 3], sections[i, 4]
        x = y
        y = b0 * x + states[i, 0]
        states[i, 0] = b1 * x - a1 * y + states[i, 1]
        states[i, 1] = b2 * x - a2 * y
    return y


@njit(cache=_CACHE)
def _lugre_feedforward(p, curve, state, v):
    """LuGreFeedforward.step; p: sigma0, sigma1, gain, period; state: eps."""
    s0 = p[0]
    rate = v - s0 * abs(v) * state[0] / _stribeck(curve, v)
    state[0] += rate * p[3]
    return (s0 * state[0] + p[1] * rate) / p[2]


@njit(cache=_CACHE)
def _steps(k0, k1, ref_p, ref_v, ref_a,
           plant_kind, drive, plant_p, curve, held_a, held_b, plant_state, sensor_p,
           words, index, spare, has_spare,
           law_kind, law_p, law_state, sections, section_state, section_count, ff_p, ff_curve, ff_state, ff_on,
           feedforward, coupled, pairs, limits, last_total, has_last, strokes,
           measurement, status,
           out_measured, out_velocity, out_effort, out_true, out_commands, out_offsets):
    """Steps k0 .. k1 - 1 of hw_sim.offline.run's loop. drive: command limit, resolution,
    gain, force noise; sensor_p: resolution, noise, period, last; measurement: position,
    velocity, effort rows; status: fault kind, step, axis, saturation count; ff_on: the
    friction feed-forward active (AxisServo._friction_active). Actuator stream of axis i: i;
    its sensor's: n + i."""
    n = ref_p.shape[1]
    nf = pairs.shape[0]
    servo_ref = np.empty(n)
    commands = np.empty(n)
    for k in range(k0, k1):
        pos, vel = measurement[0], measurement[1]
        for i in range(n):
            servo_ref[i] = ref_p[k, i]
            out_measured[k, i], out_velocity[k, i], out_effort[k, i] = pos[i], vel[i], measurement[2, i]
            out_true[k, i] = plant_state[i, 0]
        # DualStageCoupling.step and apply_offsets
        for j in range(nf):
            coarse, fine = int(pairs[j, 0]), int(pairs[j, 2])
            if not coupled:
                has_last[j] = False
                offset = 0.0
            else:
                correction = pairs[j, 1] * (ref_p[k, coarse] - pos[coarse])
                wanted = ref_p[k, fine] + correction
                total = _clamp(limits[j, 0], limits[j, 1], wanted)
                if has_last[j]:
                    total = _clamp(last_total[j] - limits[j, 2], last_total[j] + limits[j, 2], total)
                last_total[j], has_last[j] = total, True
                offset = total - ref_p[k, fine]
                if total != wanted:
                    status[3] += 1
            out_offsets[k, j] = offset
            servo_ref[fine] += offset
        # ServoGroup.step (AxisServo.step per axis)
        for i in range(n):
            v_r, a_r = (ref_v[k, i], ref_a[k, i]) if feedforward else (0.0, 0.0)
            if law_kind[i] == SLIDING_MODE:
                u = _sliding_mode(law_p[i], law_state[i], servo_ref[i], v_r, a_r, pos[i], vel[i])
            elif law_kind[i] == PPI:
                u = _ppi(law_p[i], law_state[i], servo_ref[i], pos[i], vel[i])
            else:
                u = _filters(sections[i], section_state[i], section_count[i], servo_ref[i] - pos[i])
            if ff_on[i]:
                u += _lugre_feedforward(ff_p[i], ff_curve[i], ff_state[i], v_r)
            commands[i] = u
            out_commands[k, i] = u
        # MachineSimulator.step
        if status[0] == 0:
            for i in range(n):
                if not math.isfinite(commands[i]):
                    status[0], status[1] = NON_FINITE, k
        if status[0] == 0:
            for i in range(n):
                u = commands[i]
                limit = drive[i, 0]
                applied = _quantize(_clamp(-limit, limit, u), drive[i, 1])
                disturbance = (python_random.gauss(words, index, spare, has_spare, i, drive[i, 3]) / drive[i, 2]
                               if drive[i, 3] > 0.0 else 0.0)
                if plant_kind[i] == FRICTION:
                    _friction_step(plant_p[i], curve[i], plant_state[i], drive[i, 2] * (applied + disturbance))
                else:
                    _held_step(held_a[i], held_b[i], int(plant_p[i, 0]), plant_state[i], applied + disturbance)
                measurement[2, i] = applied
            for i in range(n):
                x = plant_state[i, 0]
                if status[0] == 0 and not (strokes[i, 0] <= x <= strokes[i, 1]):
                    status[0], status[1], status[2] = STROKE, k, i
            if status[0] == 0:
                for i in range(n):       # Sensor.measure
                    noise = sensor_p[i, 1]
                    noisy = plant_state[i, 0] + (python_random.gauss(words, index, spare, has_spare, n + i, noise)
                                                 if noise > 0.0 else 0.0)
                    if not math.isfinite(noisy):
                        status[0], status[1], status[2] = RUN_AWAY, k, i
                        return
                    position = _quantize(noisy, sensor_p[i, 0])
                    measurement[1, i] = (position - sensor_p[i, 3]) / sensor_p[i, 2]
                    measurement[0, i] = position
                    sensor_p[i, 3] = position
            else:
                measurement[1, :] = 0.0
        else:
            measurement[1:, :] = 0.0


@dataclass
class Packed:
    """The arrays of :func:`_steps`, read from a run's objects (:func:`pack`)."""
    arrays: dict

    def run(self, ref_p, ref_v, ref_a, first: int, stop: int, out: dict) -> None:
        """Steps first .. stop - 1 into the rows of `out` (measured, velocity, effort, true, commands, offsets)."""
        a = self.arrays
        _steps(first, stop, ref_p, ref_v, ref_a,
               a['plant_kind'], a['drive'], a['plant_p'], a['curve'], a['held_a'], a['held_b'], a['plant_state'],
               a['sensor_p'], a['words'], a['index'], a['spare'], a['has_spare'],
               a['law_kind'], a['law_p'], a['law_state'], a['sections'], a['section_state'], a['section_count'],
               a['ff_p'], a['ff_curve'], a['ff_state'], a['ff_on'],
               a['feedforward'], a['coupled'], a['pairs'], a['limits'], a['last_total'], a['has_last'], a['strokes'],
               a['measurement'], a['status'],
               out['measured'], out['measured_velocity'], out['effort'], out['true'], out['commands'], out['offsets'])

    @property
    def fine_count(self) -> int:
        return len(self.arrays['pairs'])

    @property
    def fault(self) -> tuple[int, int, int]:
        """(kind, step, axis): kind 0 none, NON_FINITE, STROKE or RUN_AWAY."""
        status = self.arrays['status']
        return int(status[0]), int(status[1]), int(status[2])

    @property
    def saturation_count(self) -> int:
        return int(self.arrays['status'][3])

    @property
    def true_position(self) -> tuple[float, ...]:
        return tuple(self.arrays['plant_state'][:, 0].tolist())


def _curve(curve: StribeckCurve) -> list[float]:
    return [*curve.static, *curve.coulomb, *curve.omega1, *curve.omega2]


def pack(simulator, servo, coupling) -> Packed | None:
    """The compiled loop's arrays for one run of these objects (hw_sim.offline.run's), or None
    when any of them has no compiled twin here (module docstring)."""
    n = len(simulator.plants)
    if (type(simulator) is not MachineSimulator or type(servo) is not ServoGroup
            or type(coupling) is not DualStageCoupling or simulator.fault is not None
            or simulator._with_accelerometer or coupling.cartesian is not None
            or len(coupling.pairs) != len(coupling.fine) or servo.feedforward_requested is not None
            or tuple(servo.axis_names) != tuple(simulator.machine.axis_names)
            or any(type(s) is not Sensor for s in simulator.sensors)
            or any(type(s) is not AxisServo for s in servo.servos)):
        return None
    a = {'plant_kind': np.zeros(n, np.int64), 'drive': np.zeros((n, 4)), 'plant_p': np.zeros((n, 8)),
         'curve': np.zeros((n, 8)), 'held_a': np.zeros((n, 16)), 'held_b': np.zeros((n, 4)),
         'plant_state': np.zeros((n, 4)), 'sensor_p': np.zeros((n, 4)),
         'law_kind': np.zeros(n, np.int64), 'law_p': np.zeros((n, 8)), 'law_state': np.zeros((n, 1)),
         'sections': np.zeros((n, MAX_SECTIONS, 5)), 'section_state': np.zeros((n, MAX_SECTIONS, 2)),
         'section_count': np.zeros(n, np.int64), 'ff_p': np.zeros((n, 4)), 'ff_curve': np.zeros((n, 8)),
         'ff_state': np.zeros((n, 1)), 'ff_on': np.zeros(n, np.bool_)}
    for i, (plant, sensor, axis_servo) in enumerate(zip(simulator.plants, simulator.sensors, servo.servos)):
        a['drive'][i] = plant.limit, plant.resolution, plant.gain, plant.force_noise
        if type(plant) is FrictionAxis:
            a['plant_kind'][i] = FRICTION
            a['plant_p'][i] = (plant.mass, plant.viscous, plant.sigma0, plant.sigma1, plant.variation,
                               plant.wavenumber, plant.h, plant.substeps)
            a['curve'][i] = _curve(plant.curve)
            a['plant_state'][i, :3] = plant.position, plant.velocity, plant.eps
        elif type(plant) is LinearAxis:
            a['plant_kind'][i] = HELD
            a['plant_p'][i, 0] = len(plant._b)
            a['held_a'][i, :len(plant._a)] = plant._a
            a['held_b'][i, :len(plant._b)] = plant._b
            a['plant_state'][i, :len(plant._state)] = plant._state
        else:
            return None
        a['sensor_p'][i] = sensor.resolution, sensor.noise, sensor.period, sensor.last
        law = axis_servo.law
        if type(law) is SlidingModeController:
            a['law_kind'][i] = SLIDING_MODE
            a['law_p'][i] = law.lam, law.k_s, law.rho, law.d_low, law.d_high, law.m_e, law.b_e, law.period
            a['law_state'][i, 0] = law.d_hat
        elif type(law) is PPIController:
            a['law_kind'][i] = PPI
            a['law_p'][i, :4] = law.k_p, law.k_v, law.k_vi, law.period
            a['law_state'][i, 0] = law.integral
        elif type(law) is LeadLagController and len(law.sections) <= MAX_SECTIONS:
            a['law_kind'][i] = FILTERS
            a['section_count'][i] = len(law.sections)
            for j, s in enumerate(law.sections):
                a['sections'][i, j] = s.b0, s.b1, s.b2, s.a1, s.a2
                a['section_state'][i, j] = s.s1, s.s2
        else:
            return None
        friction = axis_servo._friction_active
        if friction is not None:
            if type(friction) is not LuGreFeedforward:
                return None
            a['ff_on'][i] = True
            a['ff_p'][i] = friction.sigma0, friction.sigma1, friction.gain, friction.period
            a['ff_curve'][i] = _curve(friction.curve)
            a['ff_state'][i, 0] = friction.eps
    if len({s.feedforward for s in servo.servos}) > 1:
        return None
    streams = [p.rng for p in simulator.plants] + [s.rng for s in simulator.sensors]
    a['words'], a['index'], a['spare'], a['has_spare'] = python_random.pack(streams)
    a['feedforward'] = bool(servo.servos[0].feedforward) if n else True
    a['coupled'] = bool(coupling.enabled)
    a['pairs'] = np.array([(coarse, sign, fine) for (coarse, sign), fine in zip(coupling.pairs, coupling.fine)],
                          dtype=float).reshape(-1, 3)
    a['limits'] = np.array(coupling.limits, dtype=float).reshape(-1, 3)
    a['last_total'] = np.array([0.0 if t is None else t for t in coupling._last_total])
    a['has_last'] = np.array([t is not None for t in coupling._last_total], dtype=np.bool_)
    a['strokes'] = np.array(simulator._strokes, dtype=float).reshape(-1, 2)
    measured = simulator.measurement
    a['measurement'] = np.array([measured.position, measured.velocity, measured.effort], dtype=float)
    a['status'] = np.array([0, 0, 0, coupling.saturation_count], dtype=np.int64)
    return Packed(a)
