"""Identify a feed drive on the simulated machine (issue [8/8], part 1; Yuen thesis section
4.2.1-4.2.2), offline on hw_sim as a user would on the machine: the axis runs under its own
servo about the middle of its stroke, the others hold home, and only what the machine gives
is used (the applied command,
the encoder positions) with the drive's data-sheet force constant K = K_a K_t.

* **Rigid body**: a Schroeder multisine position reference (FREQUENCIES, equal velocity
  amplitude per tone, scaled to half the axis's velocity and acceleration limits and 40 % of
  its half stroke) on a slow sine of 40 % of the half stroke (SWEEP; together they stay within
  80 % of it), raised-cosine ends, for
  DURATION; m, b, the Coulomb levels and the friction's variation along the stroke by least
  squares with 95 % intervals (machine_ctrl.identification.rigid_body.fit_rigid_body; samples
  slower than MIN_SPEED left out).
* **Stribeck curve and viscous friction**: constant-speed runs at SPEEDS in both directions,
  each holding its speed for HOLD centred on the stroke's middle; the mean force over each hold
  against its speed gives F_s, F_c, w1, w2 per direction and b
  (fit_steady_friction), with the friction's variation along the stroke found by the
  rigid-body fit averaged over each run's positions, and a bristle term: the LuGre bristles
  sliding over that variation add a force in proportion to v, which left out would be taken
  for b (fit_steady_friction).
* **LuGre bristles** sigma0, sigma1: open-loop force steps below breakaway, the presliding
  response fitted with the thesis's model and the values identified before (:func:`presliding`,
  machine_ctrl.identification.bristles).
* **Disturbance observer** (Eqs. 4.30-4.37) from the identified m, b and the run's
  resolutions (:func:`observers`).
* **Frequency response with coherence** (:func:`closed_loop_frf`): the closed loop from the
  position reference to the encoder, at rest in the middle of the stroke, excited by
  band-limited noise (FRF_BAND, FRF_RMS, FRF_DURATION), the H1 estimate and its coherence
  (machine_ctrl.identification.frequency_response), the -3 dB bandwidth with the coherence
  there, and for a law acting on the error alone the open loop's crossover (L = T/(1 - T)).

The result holds the identified values beside the simulator's true ones (hw_sim knows them:
the machine config's plant section) and the seed's (thesis Tables 4.1/4.2), and a YAML
fragment of the controllers' belief in the machine-config format (:func:`yaml_fragment`).

    machine-ctrl identify AXIS [--machine M] [--out FILE] [--json] [--jobs N]
"""
from __future__ import annotations

import math
import random

import numpy as np

from hw_sim.offline import run
from machine_ctrl.experiments import parallel
from machine_ctrl.control.lugre import StribeckCurve
from machine_ctrl.control.registry import make_law
from machine_ctrl.identification.bristles import BristleFit, PreslidingStep, fit_bristles
from machine_ctrl.identification import frequency_response as fr
from machine_ctrl.identification.disturbance_observer import disturbance_observer, quantization_step, thesis_units
from machine_ctrl.identification.rigid_body import fit_rigid_body, fit_steady_friction, lugre_curve
from machine_ctrl.identification.status import FitStatus
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.reference import Reference

# assumed: tones from 0.5 to 8 Hz: below the servo's bandwidth (~30 Hz on the coarse axes, Fig.
# 4.10), so the axis follows them, and above the friction's slow variation along the stroke
FREQUENCIES = (0.5, 0.8, 1.25, 2.0, 3.15, 5.0, 8.0)     # Hz
SWEEP = 0.25                # Hz, assumed: a slow sine of 40 % of the half stroke under the tones, so the
                            # friction is seen along the stroke (its variation, fit_rigid_body)
DURATION = 8.0              # s, assumed: two periods of the sweep, four of the lowest tone
RAMP = 0.5                  # s, raised-cosine fade in and out of the multisine
MIN_SPEED = 5e-3            # m/s, assumed: ~2.8x x_c's largest Stribeck velocity w2+ of Table 4.2 (1.79 mm/s); inside y_c's and z_c's (up to 10 mm/s)
# m/s, assumed: from ~1/7 of the smallest Stribeck velocity of Table 4.2 (0.34 mm/s) to 2/3 of the x_c limit
SPEEDS = tuple(float(v) for v in np.geomspace(5e-5, 0.1, 10))
# assumed: friction wavelengths from 5 to 100 mm looked for along the stroke (those longer than
# the multisine's span are not tried: fit_rigid_body)
WAVELENGTHS = tuple(float(w) for w in np.geomspace(5e-3, 0.1, 61))
# s at constant speed, assumed: at least 0.25 s (2500 steps at 10 kHz) and 50 um of travel, 12x
# the bristles' presliding g/sigma0 (4 um on x_c): the mean is taken over 40-90 % of the hold,
# after they have settled
HOLD = 0.25
HOLD_TRAVEL = 50e-6         # m
SPEED_ACCELERATION = 0.5    # m/s^2, assumed: the ramps to and from each speed
PRESLIDING_STEPS = 1        # assumed: open-loop force steps each way (presliding); one each way pins both
PRESLIDING_HOLD = 0.03      # s, assumed: each step held (and released) 30 ms, > 10 of the bristles' time
                            # constants 1/sqrt(sigma0/m) (1.5 ms for 4 um of presliding on 21 kg)
# assumed: the frequency response's excitation, pink noise (power falling as 1/f) on the position reference from
# 1 Hz to 1 kHz (the span of the stepped sine of Fig. 4.10, `experiment frf`, 5-1500 Hz, widened below so the
# low-frequency gain of 1 is seen), 35 um rms (the stepped sine's 50 um amplitude as an rms: large against the
# ~4 um of presliding), for 10 s; Welch lines 1.25 Hz apart or closer (at 10 kHz: 8192-sample segments, 23 averages)
FRF_BAND = (1.0, 1000.0)    # Hz
FRF_RMS = 35e-6             # m
FRF_DURATION = 10.0         # s
FRF_RESOLUTION = 1.25       # Hz
MIN_COHERENCE = 0.9         # assumed: a -3 dB point is reported where the coherence is at least 0.9 (90 % of the
                            # output's power there linear in the excitation)
# Yuen thesis Table 4.1 (m^, b^), Table 4.2 (friction, +/- directions), Table 4.3 (sigma0,
# sigma1 of the feed-forward, tuned: N/mm and N s/mm converted) and the observer gains
# K_obs of Eqs. (4.38)-(4.40) (mm and V; designed from Table 4.1's m^ and b^)
SEED = {'x_c': {'mass': 21.19, 'static': (36.38, 29.03), 'coulomb': (39.74, 26.74), 'sigma0': 9.0e5, 'sigma1': 1500.0,
                'observer': ((0.2227, 2.8518e-6), (285.1827, 0.0061), (-73.5388, -0.0020))},
        'y_c': {'mass': 59.17, 'sigma0': 9.0e5, 'sigma1': 2500.0, 'observer': ((0.1880, 1.9796e-6), (197.9680, 0.0034), (-76.1335, -0.0017))},
        'z_c': {'mass': 17.61, 'sigma0': 1.5e6, 'sigma1': 7500.0, 'observer': ((0.1993, 2.2430e-6), (224.3086, 0.0042), (-75.3177, -0.0018))},
        # Sörnmo section 2.3, robot_piezo's px, py, pz (the seed's x, y, z)
        'px': {'order': 4, 'vaf': 92.5}, 'py': {'order': 2, 'vaf': 99.5}, 'pz': {'order': 5, 'vaf': 97.1}}


def multisine(machine: MachineConfig, axis: str) -> Reference:
    """The rigid-body excitation of `axis` (module docstring); every other axis at home."""
    config = machine.axis(axis)
    period = machine.control_period
    t = np.arange(int(round(DURATION / period))) * period
    n = len(FREQUENCIES)
    x = np.zeros_like(t)
    for i, f in enumerate(FREQUENCIES):
        phase = -math.pi * i * (i + 1) / n                        # Schroeder: a low crest factor
        x += np.sin(2 * math.pi * f * t + phase) / f
    fade = np.ones_like(t)
    ramp = t < RAMP
    fade[ramp] = 0.5 - 0.5 * np.cos(math.pi * t[ramp] / RAMP)
    fade[t > t[-1] - RAMP] = fade[ramp][::-1][:int((t > t[-1] - RAMP).sum())]
    x *= fade
    v, a = np.gradient(x, period), np.gradient(np.gradient(x, period), period)
    half_stroke = 0.5 * (config.stroke[1] - config.stroke[0])
    sweep = 0.4 * half_stroke * np.sin(2 * math.pi * SWEEP * t) * fade        # across the stroke
    sweep_v = np.gradient(sweep, period)
    sweep_a = np.gradient(sweep_v, period)
    scale = min(0.5 * config.limits.velocity / np.abs(v).max(), 0.5 * config.limits.acceleration / np.abs(a).max(),
                0.4 * half_stroke / np.abs(x).max())
    return _single_axis(machine, axis, sweep + scale * x, sweep_v + scale * v, sweep_a + scale * a)


def constant_speed(machine: MachineConfig, axis: str, speed: float) -> tuple[Reference, slice]:
    """A run holding `speed` (signed) for HOLD (or HOLD_TRAVEL) centred on the stroke's middle, with
    SPEED_ACCELERATION ramps and a rest at each end; and the steps of 40-90 % of the hold."""
    period = machine.control_period
    ramp = abs(speed) / SPEED_ACCELERATION
    steps = [int(round(d / period)) for d in (0.05, ramp, max(HOLD, HOLD_TRAVEL / abs(speed)), ramp, 0.05)]
    v = np.concatenate((np.zeros(steps[0]), np.linspace(0, speed, steps[1], endpoint=False), np.full(steps[2], speed),
                        np.linspace(speed, 0, steps[3]), np.zeros(steps[4])))
    a = np.gradient(v, period)
    x = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * period)))
    start = steps[0] + steps[1]
    x -= x[start + 13 * steps[2] // 20]                  # the middle of the stroke in the middle of the steps averaged
    middle = slice(start + 4 * steps[2] // 10, start + 9 * steps[2] // 10)
    return _single_axis(machine, axis, x, v, a), middle


def _single_axis(machine: MachineConfig, axis: str, x, v, a) -> Reference:
    """`axis` at the middle of its stroke + x (the offline run starts there), the others at home."""
    index = machine.axis_names.index(axis)
    pos = np.tile(np.asarray(machine.home, float), (len(x), 1))
    vel, acc = np.zeros_like(pos), np.zeros_like(pos)
    pos[:, index] = 0.5 * sum(machine.axis(axis).stroke) + np.asarray(x)
    vel[:, index], acc[:, index] = v, a
    return Reference(machine.axis_names, machine.control_period, pos, vel, acc)


def _force_and_position(machine: MachineConfig, axis: str, reference: Reference):
    """The run of `reference`: (force over each step k-1..k+1 from the applied commands, the
    encoder position at k), N and m, aligned for central differences; and the applied commands."""
    record = run(machine, reference)
    if record.fault:
        raise RuntimeError(f'{axis}: the simulated machine faulted: {record.fault}')
    i = machine.axis_names.index(axis)
    effort = record.effort[:, i]
    force = machine.axis(axis).drive.gain * 0.5 * (effort[:-1] + effort[1:])
    return force, record.measured[:-1, i], effort


def _rigid_body_run(machine: MachineConfig, axis: str):
    """The rigid-body fit, and the encoder's and the command's resolution as the run shows them."""
    force, position, effort = _force_and_position(machine, axis, multisine(machine, axis))
    fit = fit_rigid_body(force, position, machine.control_period, MIN_SPEED, WAVELENGTHS)
    return fit, (quantization_step(position), quantization_step(effort))


def _speed_run(machine: MachineConfig, axis: str, speed: float) -> tuple[float, np.ndarray]:
    """The mean force over the middle of the hold at `speed` (N) and the positions there."""
    reference, middle = constant_speed(machine, axis, speed)
    force, position, _ = _force_and_position(machine, axis, reference)
    return float(force[middle].mean()), position[middle]


def closed_loop_frf(machine: MachineConfig, axis: str) -> dict:
    """The closed loop of `axis` from its position reference to its encoder (module docstring),
    the servo's feedback alone (the feed-forward off, the fine stages uncoupled: as the stepped
    sine of `experiment frf`): 'frequencies_hz', 'gain', 'phase_deg', 'coherence' per Welch line,
    'bandwidth_hz' (the -3 dB point, None where the coherence there is below MIN_COHERENCE),
    'coherence_at_bandwidth', 'coherent_band_hz' (the widest run of lines, in log frequency, at
    MIN_COHERENCE or more), 'crossover_hz' (a law acting on the error alone: L = T/(1 - T); else None), and
    'excitation' (what was applied)."""
    period = machine.control_period
    rate = 1.0 / period
    samples = int(round(FRF_DURATION * rate))
    segment = 2 ** math.ceil(math.log2(rate / FRF_RESOLUTION))
    rng = np.random.default_rng([machine.simulation.seed, *axis.encode(), *b'frf'])
    excitation = fr.band_limited_noise(samples, rate, FRF_BAND, FRF_RMS, rng)
    zero = np.zeros(samples)
    record = run(machine, _single_axis(machine, axis, excitation, zero, zero), dual_stage=False, feedforward=False)
    if record.fault:
        raise RuntimeError(f'{axis}: the simulated machine faulted: {record.fault}')
    i = machine.axis_names.index(axis)
    response = fr.estimate(excitation, record.measured[:, i] - 0.5 * sum(machine.axis(axis).stroke), rate, segment)
    if response.status is not FitStatus.OK:
        raise RuntimeError(f'{axis}: frequency response: {response.reason}')
    found, coherence = fr.coherent_bandwidth(response, MIN_COHERENCE)
    law = make_law(machine.axis(axis), period)
    t = response.response
    return {'frequencies_hz': response.frequencies, 'gain': np.abs(t), 'phase_deg': np.degrees(np.angle(t)),
            'coherence': response.coherence, 'bandwidth_hz': found, 'coherence_at_bandwidth': coherence,
            'coherent_band_hz': fr.coherent_band(response, MIN_COHERENCE),
            'crossover_hz': fr.crossover(response.frequencies, t / (1.0 - t)) if getattr(law, 'error_feedback', False)
            else None,
            'excitation': {'band_hz': FRF_BAND, 'rms_m': FRF_RMS, 'duration_s': FRF_DURATION, 'segment': segment,
                           'averages': response.segments}}


def presliding(machine: MachineConfig, axis: str, mass: float, steady, variation) -> BristleFit:
    """LuGre's sigma0, sigma1 (machine_ctrl.identification.bristles) from PRESLIDING_STEPS open-loop
    force steps (the servo off, the amplifier driven directly, as on the machine) of half the
    identified static level where the carriage stands, each way, from rest at the middle of
    the stroke; the model's m, b and friction curve are the identified ones, the start is the
    data's (:func:`_stiffness_from_rest`, sigma1 critical by Eq. 4.65)."""
    from hw_sim.plant import Sensor
    from hw_sim.simulator import make_plant
    config, period = machine.axis(axis), machine.control_period
    seed, middle = machine.simulation.seed, 0.5 * sum(config.stroke)
    plant = make_plant(config, period, machine.simulation.substeps, random.Random(f'{seed}:{axis}:presliding'), middle)
    sensor = Sensor(config.sensor_resolution, config.plant.sensor_noise, period, random.Random(f'{seed}:{axis}:encoder'),
                    middle)
    curves = steady.curves
    shape = StribeckCurve(*(tuple(getattr(c, name) for c in curves) for name in ('static', 'coulomb', 'omega1', 'omega2')))
    steps = []
    for _ in range(PRESLIDING_STEPS):
        for d, sign in enumerate((1.0, -1.0)):
            rest = sensor.measure(plant.sensed)[0]
            level = 1.0 if variation is None else 1.0 + variation.amplitude[d] * math.sin(
                2 * math.pi * rest / variation.wavelength + variation.phase[d])
            command = sign * 0.5 * level * curves[d].static / config.drive.gain
            positions = []
            for _ in range(int(round(PRESLIDING_HOLD / period))):
                positions.append(sensor.measure(plant.sensed)[0] - rest)
                applied = plant.step(command)
            steps.append(PreslidingStep(applied * config.drive.gain, np.array(positions),
                                        lambda v, level=level: level * shape(v)))
            for _ in range(int(round(PRESLIDING_HOLD / period))):
                plant.step(0.0)
    sigma0 = float(np.mean([_stiffness_from_rest(s) for s in steps]))
    sigma1 = max(2.0 * math.sqrt(mass * sigma0) - steady.viscous, 1.0)      # critical, Eq. (4.65)
    return fit_bristles(steps, period, mass, steady.viscous, (sigma0, sigma1))


def _stiffness_from_rest(step: PreslidingStep) -> float:
    """sigma0 from where a step comes to rest, x_ss = -(g/sigma0) ln(1 - F/g) (bristles.py),
    g the curve at rest in the step's direction: the fit's start."""
    g = step.curve(math.copysign(1e-12, step.force))
    settled = abs(float(step.position[-len(step.position) // 4:].mean()))
    return -(g / settled) * math.log1p(-abs(step.force) / g)


def observers(machine: MachineConfig, axis: str, mass: float, viscous: float, steps: tuple[float, float]) -> dict:
    """The disturbance observer (thesis Eqs. 4.30-4.37) designed as the thesis did, from the
    identified `mass` and `viscous` term and the resolutions `steps` (encoder m, command V) read
    from the run, and from hw_sim's truth (the plant's mass and damping, the config's
    resolutions): {'identified', 'true'} ObserverDesigns."""
    config, period = machine.axis(axis), machine.control_period
    gain = config.drive.gain
    return {'identified': disturbance_observer(mass, viscous, gain, period, *steps),
            'true': disturbance_observer(config.plant.mass, config.plant.damping, gain, period,
                                         config.sensor_resolution, config.drive.command_resolution)}


def identify(machine: MachineConfig, axis: str, workers: int | None = None) -> dict:
    """The identification of `axis` (module docstring): {'status', 'reason', 'axis', 'rigid_body',
    'frf', 'steady', 'true', 'seed', 'speeds', 'forces', 'bristles', 'observer'} (the later ones where
    the identification got that far)."""
    config = machine.axis(axis)
    friction = config.plant.friction if config.plant is not None else None
    if config.kind != 'linear' or config.drive.mass is None or config.control is None or config.stroke is None \
            or friction is None:
        missing = [what for what, absent in (
            ('a linear joint', config.kind != 'linear'), ('a force drive (mass, damping)', config.drive.mass is None),
            ('a servo law', config.control is None), ('a stroke', config.stroke is None),
            ('guideway friction (plant.friction)', friction is None)) if absent]
        return {'status': 'refused', 'axis': axis,
                'reason': f'{axis}: identify takes a controlled linear axis with a stroke, a force drive and guideway '
                          f'friction; {axis} lacks {", ".join(missing)}'}
    jobs = [(machine, axis), (machine, axis)] + [(machine, axis, sign * v) for sign in (1.0, -1.0) for v in SPEEDS]
    functions = [_rigid_body_run, closed_loop_frf] + [_speed_run] * (len(jobs) - 2)
    try:
        outcomes = parallel.run_all(_call, list(zip(functions, jobs)), workers)
    except RuntimeError as exc:             # the simulated machine faulted (stroke, limits)
        return {'status': 'refused', 'reason': str(exc), 'axis': axis}
    (body, steps), frf, speed_runs = outcomes[0], outcomes[1], outcomes[2:]
    forces = np.abs(np.array([force for force, _ in speed_runs])).reshape(2, len(SPEEDS))
    result = {'axis': axis, 'rigid_body': body, 'frf': frf, 'speeds': list(SPEEDS), 'forces': forces.tolist(),
              'true': true_values(machine, axis), 'seed': SEED.get(axis, {})}
    if body.status is not FitStatus.OK:
        return {**result, 'status': 'refused', 'reason': f'rigid body: {body.reason}'}
    scales, slopes = np.ones_like(forces), None
    if body.variation is not None:      # s(x) = 1 + A sin(k x + phase) and ds/dx, averaged over each run
        k, slopes = 2 * math.pi / body.variation.wavelength, np.zeros_like(forces)
        for i, (_, positions) in enumerate(speed_runs):
            d, j = i // len(SPEEDS), i % len(SPEEDS)
            angle = k * positions + body.variation.phase[d]
            scales[d, j] = float(np.mean(1.0 + body.variation.amplitude[d] * np.sin(angle)))
            slopes[d, j] = float(np.mean(body.variation.amplitude[d] * k * np.cos(angle)))
    steady = fit_steady_friction(np.tile(SPEEDS, (2, 1)), forces, scales, slopes)
    result['steady'] = steady
    if steady.status is not FitStatus.OK:
        return {**result, 'status': 'refused', 'reason': f'steady friction: {steady.reason}'}
    result['bristles'] = presliding(machine, axis, body.mass.value, steady, body.variation)
    if result['bristles'].status is not FitStatus.OK:
        return {**result, 'status': 'refused', 'reason': f'presliding: {result["bristles"].reason}'}
    result['observer'] = observers(machine, axis, body.mass.value, steady.viscous, steps)
    problems = [f'{which}: {design.reason}' for which, design in result['observer'].items()
                if design.status is not FitStatus.OK]
    if problems:
        return {**result, 'status': 'refused', 'reason': f'disturbance observer: {"; ".join(problems)}'}
    return {**result, 'status': 'ok', 'reason': ''}


def identify_axis(machine: MachineConfig, axis: str, workers: int | None = None) -> dict:
    """The identification the axis's drive calls for, so one command serves every machine
    (issue [8/8] part 3): a flexure stage (voice_coil) by its stepped-sine frequency response
    and the grey-box fit of Ding section 5.5 (:mod:`fts_identify`), a piezo stage by a chirp
    and N4SID (Sörnmo section 2.3, :mod:`piezo_milling`), any other drive as a feed drive
    (:func:`identify`). The result's 'method' names which; the other two give 'rows' of
    (parameter, seed, true, identified); a piezo stage's 'model' is the identified model in
    the config's modal form, the belief file of its LQG (:func:`yaml_fragment`); a flexure
    stage's 'model' the grey-box parameters, the belief file of its H2 law (its PID takes no
    identified values; README "Truth and belief")."""
    method = method_of(machine, axis)
    if method == 'frf_grey_box':
        return _flexure_frf(machine, axis)
    if method == 'subspace':
        return _piezo_subspace(machine, axis)
    return {**identify(machine, axis, workers), 'method': 'feed_drive'}


def method_of(machine: MachineConfig, axis: str) -> str:
    """'frf_grey_box' (a voice_coil flexure stage), 'subspace' (a piezo stage) or 'feed_drive'."""
    return {'voice_coil': 'frf_grey_box', 'piezo': 'subspace'}.get(machine.axis(axis).drive.type, 'feed_drive')


def _flexure_frf(machine: MachineConfig, axis: str) -> dict:
    """Ding section 5.5 on the axis: the grey-box parameters beside the seed's and hw_sim's."""
    from machine_ctrl.experiments import fts_identify as fts
    config = machine.axis(axis)
    flexure = config.plant.flexure
    true = {'m12': config.plant.mass, 'c2': config.plant.damping, 'k2': flexure.stiffness,
            'm4': flexure.secondary_mass, 'c4': flexure.secondary_damping, 'k4': flexure.secondary_stiffness}
    start = {k: fts.TABLE_5_2[k] * fts.START[k] for k in fts.TABLE_5_2}
    fitted = fts.fit(fts.stepped_sine(machine, axis=axis), machine, start, axis)
    result = {'axis': axis, 'method': 'frf_grey_box',
              'rows': [(f'{k} ({fts.UNITS[k]})', fts.TABLE_5_2[k], true[k], fitted['params'][k]) for k in fts.TABLE_5_2],
              'notes': [f'stepped sine in the closed loop, {len(fts.FREQUENCIES)} lines {fts.FREQUENCIES[0]:g}-'
                        f'{fts.FREQUENCIES[-1]:g} Hz; fit from {", ".join(f"{v:.3g}" for v in fts.START.values())} x '
                        f'Table 5-2; RMS of log(model / measured) {fitted["rms_log_residual"]:.2e}']}
    if not fitted['success']:
        return {**result, 'status': 'refused', 'reason': f'the grey-box fit did not converge: {fitted["message"]}'}
    return {**result, 'model': {**fitted['params'], 'rms_log_residual': fitted['rms_log_residual']},
            'status': 'ok', 'reason': ''}


def _piezo_subspace(machine: MachineConfig, axis: str) -> dict:
    """Sörnmo section 2.3 on the axis: the N4SID model's order, VAF and first eigenfrequency,
    the last beside hw_sim's lowest mode."""
    from hw_sim.piezo_stage import PiezoAxisModel
    from machine_ctrl.experiments import piezo_milling as pm
    from machine_ctrl.identification.subspace import identify as n4sid
    from machine_ctrl.identification.subspace import modal_form
    config = machine.axis(axis)
    model = PiezoAxisModel.from_axis(config)
    rng = np.random.default_rng([machine.simulation.seed, *axis.encode()])
    found = n4sid(*pm.chirp_record(model, rng))
    seed = SEED.get(axis, {})
    result = {'axis': axis, 'method': 'subspace',
              'notes': [f'chirp {pm.CHIRP_HZ[0]:g}-{pm.CHIRP_HZ[1]:g} Hz for {pm.CHIRP_TIME:g} s at 1 kHz, decimated '
                        f'{pm.DECIMATION}x; N4SID, the order at the singular values\' gap']}
    if not found.ok:
        return {**result, 'status': 'refused', 'reason': f'N4SID: {found.reason}'}
    result['rows'] = [('model order', seed.get('order'), None, found.model.order),
                      ('VAF (%)', seed.get('vaf'), None, found.vaf),
                      ('first eigenfrequency (Hz)', None, min(f for f, _ in model.modes),
                       pm.first_eigenfrequency(found.model))]
    form = modal_form(found.model)
    if form.reason:
        return {**result, 'status': 'refused', 'reason': f'the identified model has no modal form: {form.reason}'}
    result['model'] = {'modes': [{'omega': w, 'zeta': z} for w, z in form.modes], 'real_pole': form.real_pole,
                       'order': found.model.order, 'vaf': found.vaf, 'static_gain': found.model.static_gain()}
    return {**result, 'status': 'ok', 'reason': ''}



def _call(function, job):
    return function(*job)


def true_values(machine: MachineConfig, axis: str) -> dict:
    """What hw_sim simulates for `axis`: the plant's (true) mass, damping and friction (N, m/s)."""
    config = machine.axis(axis)
    out = {'mass': config.plant.mass, 'viscous': config.plant.damping}
    friction = config.plant.friction
    if friction is not None:
        out.update(static=friction.static, coulomb=friction.coulomb, omega1=friction.omega1, omega2=friction.omega2,
                   variation=friction.variation, variation_wavelength=friction.variation_wavelength,
                   sigma0=friction.sigma0, sigma1=friction.sigma1)
    return out


def yaml_fragment(machine: MachineConfig, result: dict) -> str:
    """The belief file of an identified axis (:func:`identify_axis`): a feed drive's
    (:func:`feed_drive_fragment`), a flexure stage's (:func:`flexure_fragment`) or a piezo
    stage's model (:func:`piezo_fragment`)."""
    method = result.get('method', 'feed_drive')      # identify()'s own result names none
    return {'feed_drive': feed_drive_fragment, 'frf_grey_box': flexure_fragment,
            'subspace': piezo_fragment}[method](machine, result)


def flexure_fragment(machine: MachineConfig, result: dict) -> str:
    """A flexure stage's grey-box parameters as the drive's mass, damping and flexure (the
    controllers' model its H2 law designs from; the plant section, hw_sim's truth, is not
    touched)."""
    axis, p = result['axis'], result['model']
    return '\n'.join([
        f'# machine-ctrl identify {axis} --machine {machine.name}: offline on hw_sim (simulation.seed '
        f'{machine.simulation.seed}); stepped sine and the grey-box fit of Ding section 5.5, RMS of '
        f'log(model / measured) {p["rms_log_residual"]:.2e}',
        'axes:',
        f'  {axis}:',
        '    drive:',
        f'      mass: {p["m12"]:.5g}          # m12, kg',
        f'      damping: {p["c2"]:.5g}        # c2, N*s/m',
        '      flexure:',
        f'        stiffness: {p["k2"]:.5g}             # k2, N/m',
        f'        secondary_mass: {p["m4"]:.5g}        # m4, kg',
        f'        secondary_stiffness: {p["k4"]:.5g}   # k4, N/m',
        f'        secondary_damping: {p["c4"]:.5g}     # c4, N*s/m']) + '\n'


def piezo_fragment(machine: MachineConfig, result: dict) -> str:
    """A piezo stage's identified model as the drive's modes and real pole (the controllers'
    model its LQG designs from; plant.modes, hw_sim's truth, is not touched)."""
    axis, model = result['axis'], result['model']
    lines = [f'# machine-ctrl identify {axis} --machine {machine.name}: offline on hw_sim (simulation.seed '
             f'{machine.simulation.seed}); N4SID of order {model["order"]}, VAF {model["vaf"]:.3f} %, in modal form '
             '(static gain 1, zeros dropped)',
             'axes:',
             f'  {axis}:',
             '    drive:',
             '      modes:']
    lines += [f'        - {{omega: {m["omega"]:.6g}, zeta: {m["zeta"]:.4g}}}    # {m["omega"] / (2 * math.pi):.3f} Hz'
              for m in model['modes']]
    pole = model['real_pole']      # always written: 0 replaces a real pole the config's model has
    lines.append(f'      real_pole: {pole:.6g}    # rad/s' + (f', {pole / (2 * math.pi):.3f} Hz' if pole else ' (none)'))
    lines.append(f'# the identified static gain, {model["static_gain"]:.4g}, is not in the modal form (it has 1); the '
                 f'reference notch (control.lqg.notch_frequency) is the config\'s')
    return '\n'.join(lines) + '\n'


def feed_drive_fragment(machine: MachineConfig, result: dict) -> str:
    """The identified values as a fragment of the machine YAML (to merge by hand, or to give to
    the tools that take one), each with its 95 % interval or fit residual in a comment. They are
    the controllers' belief: the drive's mass and damping, and the LuGre feed-forward's curve
    (Eqs. 4.59-4.61, :func:`lugre_curve`) and bristles (:func:`presliding`) where the axis's
    law has one; hw_sim's truth (the plant
    section) is not touched. The two directions' Stribeck curves and the friction's variation
    along the stroke, for which the laws have no place, are comments."""
    body, steady, axis = result['rigid_body'], result['steady'], result['axis']
    fits = steady.curves

    def pair(name):
        return f'[{getattr(fits[0], name):.5g}, {getattr(fits[1], name):.5g}]'
    worst = max(f.worst_relative_residual for f in fits)
    lines = [f'# machine-ctrl identify {axis} --machine {machine.name}: offline on hw_sim (simulation.seed '
             f'{machine.simulation.seed})',
             f'# Stribeck curve (Eq. 4.41), (positive, negative) direction, worst fit residual {100 * worst:.1f} %:',
             f'#   static {pair("static")} N, coulomb {pair("coulomb")} N, omega1 {pair("omega1")} m/s, '
             f'omega2 {pair("omega2")} m/s']
    if body.variation is not None:
        v = body.variation
        lines.append(f'# friction along the stroke: +-{v.amplitude[0]:.3g} / +-{v.amplitude[1]:.3g} (positive / negative), '
                     f'wavelength {v.wavelength:.4g} m, phase at x = 0 {v.phase[0]:.2f} / {v.phase[1]:.2f} rad')
    lines += ['axes:',
              f'  {axis}:',
              '    drive:',
              f'      mass: {body.mass.value:.5g}        # kg, +-{body.mass.half_width:.2g} (95 %), rigid-body fit',
              f'      damping: {steady.viscous:.5g}     # N*s/m, from the constant-speed runs']
    control = machine.axis(axis).control
    if control is not None and control.lugre_feedforward is not None:
        curve = lugre_curve(steady, result['speeds'])
        bristles = result['bristles']
        lines += ['    control:',
                  '      lugre_feedforward:',
                  f'        static: {curve.static:.5g}          # F_s, N, Eq. (4.60)',
                  f'        coulomb: {curve.coulomb:.5g}         # F_c, N, Eq. (4.61)',
                  f'        stribeck_velocity: {curve.stribeck_velocity:.4g}   # Omega_s, m/s, Eq. (4.59) fitted (Eq. 4.45)',
                  f'        sigma0: {bristles.sigma0:.5g}       # N/m, presliding steps (Eq. 4.58)',
                  f'        sigma1: {bristles.sigma1:.5g}         # N*s/m, presliding steps (Eq. 4.62)']
    return '\n'.join(lines) + '\n'


def observer_steps(observer: dict) -> str:
    """The resolutions the identified observer was designed with, as text."""
    r_x, _, r_u, _ = observer['identified'].noise
    return f'encoder {math.sqrt(12 * r_x) * 1e6:.4g} um, command {math.sqrt(12 * r_u) * 1e3:.4g} mV'


def table(result: dict) -> str:
    """seed | true (hw_sim) | identified | error, per parameter."""
    if result['status'] != 'ok':
        return f'{result["axis"]}: refused: {result["reason"]}'
    if result.get('method', 'feed_drive') != 'feed_drive':
        return _rows_table(result)
    body, steady, true, seed = result['rigid_body'], result['steady'], result['true'], result['seed']
    lines = [f'{result["axis"]}: identified offline on hw_sim (the simulator\'s true values beside)',
             f'  {"parameter":26s} {"seed":>9s} {"true":>9s} {"identified":>11s} {"95 %":>8s} {"error":>8s}']

    def row(name, s, t, value, half=None):
        lines.append(f'  {name:26s} {"-" if s is None else f"{s:.4g}":>9s} {t:9.4g} {value:11.4g} '
                     f'{"" if half is None else f"{half:.2g}":>8s} {100 * (value / t - 1):7.2f}%')
    row('mass (kg)', seed.get('mass'), true['mass'], body.mass.value, body.mass.half_width)
    row('viscous (N s/m)', None, true['viscous'], steady.viscous)
    for k, direction in enumerate(('positive', 'negative')):
        for name, unit in (('static', 'N'), ('coulomb', 'N'), ('omega1', 'm/s'), ('omega2', 'm/s')):
            row(f'{name} {direction} ({unit})', seed.get(name, (None, None))[k], true[name][k],
                getattr(steady.curves[k], name))
    if body.variation is not None and true.get('variation'):
        v = body.variation
        row('variation positive (1)', None, true['variation'], v.amplitude[0])
        row('variation negative (1)', None, true['variation'], v.amplitude[1])
        row('variation wavelength (m)', None, true['variation_wavelength'], v.wavelength)
    if not math.isnan(steady.bristle_time) and 'sigma1' in true:
        row('bristle term tau (s)', None, true['sigma1'] / true['sigma0'], steady.bristle_time)
    if not math.isnan(steady.bristle_time):
        lines.append('  tau: the steady fit\'s bristle term (fit_steady_friction), beside the true sigma1/sigma0: it '
                     'also takes up the bristles\' lag behind the varying friction, so it keeps b right but is not '
                     'sigma1/sigma0 (those: the presliding steps)')
    bristles = result['bristles']
    row('sigma0 (N/m)', seed.get('sigma0'), true['sigma0'], bristles.sigma0)
    row('sigma1 (N s/m)', seed.get('sigma1'), true['sigma1'], bristles.sigma1)
    lines.append(f'  sigma0, sigma1 from {bristles.steps} open-loop presliding steps (half the static level), residual '
                 f'{bristles.residual_rms * 1e6:.2g} um rms; the seed\'s are Table 4.3\'s tuned feed-forward values')
    observer = result['observer']
    identified, true_gain = thesis_units(observer['identified'].gain), thesis_units(observer['true'].gain)
    seed_gain = seed.get('observer')
    for i, state in enumerate(('x', 'v', 'd')):
        for j, measured in enumerate(('x_m', 'v_m')):
            row(f'K_obs {state} <- {measured}', None if seed_gain is None else seed_gain[i][j], true_gain[i, j],
                identified[i, j])
    lines.append(f'  K_obs in the thesis\'s mm and V (Eqs. 4.38-4.40); the seed\'s from Table 4.1 m^, b^ '
                 f'(b^ before its correction, Eq. 4.43); identified from the fitted m, b and the run\'s resolutions '
                 f'({observer_steps(observer)})')
    lines += frf_lines(result['frf'])
    lines.append(f'  rigid body from {body.samples} samples faster than {MIN_SPEED * 1e3:g} mm/s, residual '
                 f'{body.residual_rms:.3g} N rms (its own b: {body.viscous.value:.4g} N s/m, Coulomb '
                 f'{body.coulomb[0].value:.4g} / {body.coulomb[1].value:.4g} N); the steady-friction fit\'s worst '
                 'relative residual: ' + ', '.join(f'{d} {100 * c.worst_relative_residual:.2f} %'
                                                   for d, c in zip(('positive', 'negative'), steady.curves)))
    return '\n'.join(lines)


def frf_lines(frf: dict) -> list[str]:
    """The closed loop's frequency response (:func:`closed_loop_frf`) as text: the bandwidths,
    the coherent band, and gain / coherence at a few frequencies."""
    f, gain, coherence, x = frf['frequencies_hz'], frf['gain'], frf['coherence'], frf['excitation']

    def hz(value):
        return '-' if value is None else f'{value:.1f} Hz'
    band = frf['coherent_band_hz']
    lines = [f'  closed loop, reference -> encoder at rest (feedback alone; pink noise {x["band_hz"][0]:g}-'
             f'{x["band_hz"][1]:g} Hz, {x["rms_m"] * 1e6:g} um rms, {x["duration_s"]:g} s, {x["averages"]} Welch '
             f'averages): -3 dB at {hz(frf["bandwidth_hz"])} (coherence {frf["coherence_at_bandwidth"]:.3f}), '
             f'open-loop crossover {hz(frf["crossover_hz"])}; coherence >= {MIN_COHERENCE:g} from '
             + ('-' if band is None else f'{band[0]:.1f} to {band[1]:.1f} Hz')]
    points = [int(np.argmin(np.abs(f - target))) for target in (2, 5, 10, 20, 50, 100, 200, 500)]
    lines.append('    ' + ', '.join(f'{f[k]:.0f} Hz {20 * math.log10(gain[k]):+.1f} dB (coh. {coherence[k]:.2f})'
                                      for k in points))
    return lines


def _rows_table(result: dict) -> str:
    """The table of a method that gives (parameter, seed, true, identified) rows."""
    lines = [f'{result["axis"]}: identified offline on hw_sim ({result["method"]}; the simulator\'s true values beside)',
             f'  {"parameter":28s} {"seed":>9s} {"true":>9s} {"identified":>11s} {"error":>8s}']
    for name, seed, true, value in result['rows']:
        error = '' if true is None else f'{100 * (value / true - 1):7.2f}%'
        lines.append(f'  {name:28s} {"-" if seed is None else f"{seed:.4g}":>9s} {"-" if true is None else f"{true:.4g}":>9s} '
                     f'{value:11.4g} {error:>8s}')
    return '\n'.join(lines + [f'  {note}' for note in result.get('notes', ())])
