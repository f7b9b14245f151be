"""Sörnmo thesis (seed ``004_33b29b0855b96c5a.txt``) Table 3.1, simulation rows, and the
adaptation run of Fig. 3.7: adaptive IMC mid-ranging (AIMC) against MVPC and MVPC with
anti-windup on the plant of Eq. (3.17), h = 0.004 s, u_sat = 10, IAE of Eq. (3.19)
normalized by the AIMC's.

    python -c "from machine_ctrl.experiments.midrange import table_3_1, format_table; \\
               print(format_table(table_3_1()))"

What the seed fixes: the plant and desired responses (3.17)-(3.18), h, u_sat, that Table 3.1
is "the average Integrated Absolute Error (IAE) over several step responses" (§3.5; its
caption: "Normalized IAE value of step responses"), the step heights r_r of the rows, that
row 3 adds measurement noise, that the estimators get an initial guess and an estimation
phase with a low-amplitude square wave (§3.2, §3.3), Fig. 3.6's reference ("a ramped
square-wave with a superimposed low-frequency sine wave", §3.3) and the gain steps of
Fig. 3.7 (+50 % at 8 s, then -60 % at 16 s, Fig. 3.6's input without the ramp). What it
leaves open is in :class:`Choices` (each marked ``# assumed:`` with its reason);
:func:`table_3_1` also runs each of them at a low and a high value, one at a time, and
reports the spread of every ratio.

History, said because three choices were made after results were seen (2026-11-28): the
table was first run on Fig. 3.6's ramped square wave with its sine, which §3.3 names for that
figure, not for the table; it is now run on step responses, as §3.5 and the caption say (the
ramped reference's ratios are still printed, for information), with a step period chosen in
the same change (step_period). And the MVPC's feedforward F (a reading of Fig. 3.2, an image
the seed text lacks) was 1, a static decoupling; it is now 0, which makes the "MVPC" columns
plain valve position control (VPC): the modification, as we read it, is gone. The reason is
the tuning sentence of §3.2: both PIs "designed using the same desired closed-loop system as
for the proposed controller". With F = 0 the loop the slow PI closes is exactly H_cl^s, so
each direct-synthesis PI gives its loop its design response; with F = 1 it is
-(1 - H_cl^f + H_cl^s), and the design does not hold (the fast loop sees half its gain).
F = 1 stays in the spread. Only the combination agrees: rows 1 and 2 (MVPC+AW / MVPC):

    F = 0, steps (8 s)     1.528;  1.447 / 1.544      (seed 1.525; 1.458 / 1.555)
    F = 0, steps (4 s)     1.357;  1.317 / 1.423
    F = 0, ramped wave     1.250;  1.237 / 1.337
    F = 1, steps (8 s)     2.137;  1.718 / 1.687
    F = 1, ramped wave     1.838;  1.497 / 1.460      (the reading before)

and with it row 2's anti-windup ordering (MVPC+AW better than MVPC) is the seed's; with the
old readings row 1 was +20 % and that ordering reversed.

Definitions used here (also assumed where the seed is silent):

* r_r is the height of each square-wave step (the reference goes 0 -> r_r -> 0 ...): §3.5
  says row 1's r_r "is small enough to fulfill |u_f| <= u_sat"; a step of height S gives the
  AIMC an inner control of k_c S (b_f0 - b_s0)/b_f0 = 4.5 S, within 10 for S = 1.5 but not
  for a step of 2 r_r = 3. In Figs. 3.6-3.7 the ramp and sine scale with r_r too.
* IAE (3.19) is summed over the whole run of steps (a sum over several step responses; the
  ratio to the AIMC's is the ratio of their averages), h sum_k |r_r,k - y_r,k|, with the true
  y_r (the simulation knows it; noise is a sensor property, not an error of the position).
* Each controller starts from rest at t = 0 on the same reference. The AIMC's estimators
  start from the state the estimation phase left (the phase runs on the same plant, which
  is then put back at rest).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.control.midranging import (AIMC, AIMCConfig, MidRangingPlant, MVPC,
                                             MVPCConfig, PlantConfig)

# seed 004, Table 3.1 "Normalized IAE value of step responses", simulation rows:
# (r_r, noise?) -> (MVPC+AW, MVPC), AIMC = 1.000
SEED_ROWS = (
    ('1. Sim, r_r = 1.5', 1.5, False, 1.525, 1.525),
    ('2. Sim, r_r = 5', 5.0, False, 1.458, 1.555),
    ('3. Sim, r_r = 5, noise', 5.0, True, 1.380, 1.474),
)
TOLERANCE = 0.10          # the brief's target: within 10 % of the table
FIG37_STEPS = ((8.0, 1.5), (16.0, 0.4))   # seed 004 §3.3: H_p^f gain +50 % at 8 s, -60 % at 16 s
FIG37_R = 5.0             # assumed: Fig. 3.7 at the larger table height, where the DRG acts
# (§3.3: the gain increase "leads to less saturation and a higher alpha_k": saturation occurs)
FIG37_TOL = 0.05          # convergence tolerance of the gain estimate (5 % of the new gain)


@dataclass(frozen=True)
class Choices:
    """Everything Table 3.1 (step_period onwards but square_period, ramp, sine_*) and Figs.
    3.6-3.7 (square_period, ramp, sine_*, duration) need that seed 004 does not state."""
    step_period: float = 8.0       # assumed: Table 3.1's square wave of steps, 8 s: each 4 s half
    # is 4 time constants of the slow loop (tau_s = 1 s, Eq. 3.17), so every step response settles
    # before the next, and 24 s hold 6 of them ("several step responses", §3.5)
    square_period: float = 4.0     # assumed: Figs. 3.6-3.7's square wave, 4 s. Fig. 3.7's gain steps at 8 s and 16 s fall on
    # period boundaries, the text says a change shows "for one period of the square-wave", and
    # a 2 s half period is 2 time constants of the slow loop (tau_s = 1 s, Eq. 3.17) and 20 of
    # the fast one: each step settles in the fast loop, the slow one takes over visibly.
    ramp: float = 0.05             # assumed: ramp slope 0.05 r_r per s (1.2 r_r over 24 s): a
    # ramp of the size of the steps, the "ramped square-wave" of Fig. 3.6 that moves y_s away.
    sine_amplitude: float = 0.1    # assumed: 0.1 r_r, a visible but secondary "superimposed" sine
    sine_frequency: float = 0.1    # assumed: 0.1 Hz, "low-frequency": 2.5 square periods
    duration: float = 24.0         # assumed: 24 s, 3 x 8 s (Fig. 3.7's segments), Fig. 3.6's
    # disturbance at 18 s inside it
    forgetting: float = 0.995      # assumed: see AIMCConfig.forgetting
    p0: float = 100.0              # assumed: see AIMCConfig.p0
    guess_bandwidth: float = 0.5   # assumed: see AIMCConfig.guess_bandwidth
    noise: float = 0.05            # assumed: white Gaussian noise std 0.05 on each measured
    # position (y_f, y_s, y_r), 1 % of the row-3 step height 5: "substantial" (§3.6) for a
    # position sensor, small against the steps. Seed 0 of numpy's default generator.
    tracking_time: float | None = None   # assumed: see MVPCConfig.tracking_time (None: T_i)
    feedforward: float = 0.0       # assumed: the MVPC's feedforward F (MVPCConfig.feedforward): 0, the
    # reading under which §3.2's tuning sentence holds (module docstring, History); 1 in the spread
    estimation_time: float = 8.0   # assumed: estimation phase of 8 s (4 periods of its square)
    estimation_amplitude: float = 0.5    # assumed: "low amplitude square-wave" (§3.3) of 0.5
    # on both loop references: inner u_f = 5 x 0.5 = 2.5, clear of u_sat as §3.2 requires
    estimation_period: float = 2.0       # assumed: 2 s, each half one slow time constant
    noise_seed: int = 0

    def aimc(self) -> AIMCConfig:
        return AIMCConfig(forgetting=self.forgetting, p0=self.p0,
                          guess_bandwidth=self.guess_bandwidth)


NOMINAL = Choices()

# one-at-a-time grid: each unstated choice at a low and a high value (half / double, or for
# the forgetting factor half / double its memory 1/(1 - lambda)); the tracking time None
# stands for T_i, so its grid is T_i/2 and 2 T_i (T_i = h a/b = 0.096 s for Eq. 3.17); the
# feedforward, nominally 0, at the former reading 1 and half of it.
_TI = PlantConfig().h * PlantConfig().fast_model()[0] / PlantConfig().fast_model()[1]
GRID = {
    'step_period': (4.0, 16.0),
    'forgetting': (0.99, 0.9975),
    'p0': (50.0, 200.0),
    'guess_bandwidth': (0.25, 1.0),
    'noise': (0.025, 0.1),
    'tracking_time': (_TI / 2.0, 2.0 * _TI),
    'feedforward': (0.5, 1.0),      # the static decoupling (1: the reading before 2026-11-28) and half of it
}
# which controllers a choice affects (the others' runs are shared)
_AFFECTS = {
    'forgetting': ('aimc',), 'p0': ('aimc',), 'guess_bandwidth': ('aimc',),
    'tracking_time': ('mvpc_aw',), 'feedforward': ('mvpc', 'mvpc_aw'),
}


def steps(r_r: float, choices: Choices) -> np.ndarray:
    """Table 3.1's reference: a square wave 0 / r_r (period step_period, high first) for the
    run's duration: step responses (§3.5)."""
    h = PlantConfig().h
    t = np.arange(int(round(choices.duration / h))) * h
    return r_r * ((t % choices.step_period) < choices.step_period / 2.0).astype(float)


def reference(r_r: float, choices: Choices, ramp: bool = True) -> np.ndarray:
    """Fig. 3.6's r_r,k for k = 0..N-1: square wave 0 / r_r (square_period, high first) plus a
    ramp and a sine, all scaled by r_r (§3.3, "a ramped square-wave with a superimposed
    low-frequency sine wave"; Fig. 3.7: the same without the ramp)."""
    h = PlantConfig().h
    t = np.arange(int(round(choices.duration / h))) * h
    square = ((t % choices.square_period) < choices.square_period / 2.0).astype(float)
    r = square + choices.sine_amplitude * np.sin(2.0 * math.pi * choices.sine_frequency * t)
    if ramp:
        r = r + choices.ramp * t
    return r_r * r


def _noise(choices: Choices, sigma: float, n: int, stream: int) -> tuple[list, list, list]:
    if sigma <= 0.0:
        z = [0.0] * n
        return z, z, z
    rng = np.random.default_rng([choices.noise_seed, stream])
    e = rng.normal(0.0, sigma, size=(3, n))
    return e[0].tolist(), e[1].tolist(), e[2].tolist()


def _estimation_phase(aimc: AIMC, plant: MidRangingPlant, choices: Choices, sigma: float,
                      cache: dict | None = None) -> None:
    """§3.2: excite both loops directly with a low-amplitude square wave, estimators running.
    `cache` keeps the estimators' end state per (estimator and phase choices, noise): the
    phase does not depend on the reference, and the grid would repeat it."""
    key = (choices.aimc(), choices.estimation_time, choices.estimation_amplitude,
           choices.estimation_period, choices.noise_seed, sigma)
    if cache is not None and key in cache:
        state = cache[key]
        for rls, (theta, P) in zip((aimc.rls_f, aimc.rls_s), state[:2]):
            rls.theta, rls.P = list(theta), [list(row) for row in P]
        aimc.model_f, aimc.model_s = state[2:]
        aimc.restart()
        return
    h = plant.config.h
    n = int(round(choices.estimation_time / h))
    nf, ns, _ = _noise(choices, sigma, n, 1)
    for k in range(n):
        w = choices.estimation_amplitude if (k * h) % choices.estimation_period < \
            choices.estimation_period / 2.0 else 0.0
        aimc.estimate_only(w, w, plant.y_f + nf[k], plant.y_s + ns[k])
        plant.step(w, w)
    plant.reset()
    aimc.restart()
    if cache is not None:
        cache[key] = ((list(aimc.rls_f.theta), [list(r) for r in aimc.rls_f.P]),
                      (list(aimc.rls_s.theta), [list(r) for r in aimc.rls_s.P]),
                      aimc.model_f, aimc.model_s)


def run(controller: str, r: np.ndarray, choices: Choices, sigma: float = 0.0,
        gain_steps=(), record: bool = False, estimation_cache: dict | None = None) -> dict:
    """One closed-loop run of 'aimc', 'mvpc' or 'mvpc_aw' on reference r (from rest).

    Returns the IAE (3.19) and, with `record`, the signals (y_r, y_f, y_s, w_f, u_f, and for
    the AIMC alpha and the fast model's estimate (a, b) per sample)."""
    pc = PlantConfig()
    h = pc.h
    plant = MidRangingPlant(pc)
    n = len(r)
    nf, ns, nr = _noise(choices, sigma, n, 2)
    steps = sorted((int(round(t / h)), g) for t, g in gain_steps)
    rec = {key: [] for key in ('y_r', 'y_f', 'y_s', 'w_f', 'u_f', 'alpha', 'a_f', 'b_f')} \
        if record else None
    if controller == 'aimc':
        ctrl = AIMC(pc, choices.aimc())
        _estimation_phase(ctrl, plant, choices, sigma, estimation_cache)
    elif controller in ('mvpc', 'mvpc_aw'):
        ctrl = MVPC(pc, MVPCConfig(anti_windup=controller == 'mvpc_aw',
                                   tracking_time=choices.tracking_time,
                                   feedforward=choices.feedforward))
    else:
        raise ValueError(f"unknown controller {controller!r} (aimc, mvpc, mvpc_aw)")
    rl = r.tolist()
    iae = 0.0
    peak_u = 0.0
    is_aimc = controller == 'aimc'
    ctrl_step, plant_step = ctrl.step, plant.step
    next_change = steps[0][0] if steps else -1
    for k in range(n):
        if k == next_change:
            plant.gain_factor *= steps.pop(0)[1]
            next_change = steps[0][0] if steps else -1
        y_f, y_s = plant.y_f, plant.y_s
        y_r = y_f + y_s
        if is_aimc:
            w_f, w_s = ctrl_step(rl[k], y_r + nr[k], y_f + nf[k], y_s + ns[k])
        else:
            w_f, w_s = ctrl_step(rl[k], y_r + nr[k], plant.u_applied - plant.u_f)
        plant_step(w_f, w_s)
        iae += abs(rl[k] - y_r)
        u = plant.u_f
        if u > peak_u or -u > peak_u:
            peak_u = abs(u)
        if rec is not None:
            rec['y_r'].append(y_r)
            rec['y_f'].append(y_f)
            rec['y_s'].append(y_s)
            rec['w_f'].append(w_f)
            rec['u_f'].append(u)
            if is_aimc:
                rec['alpha'].append(ctrl.alpha)
                rec['a_f'].append(ctrl.model_f[0])
                rec['b_f'].append(ctrl.model_f[1])
    out = {'iae': iae * h, 'peak_u_f': peak_u, 'final_gain_factor': plant.gain_factor}
    if rec is not None:
        out['signals'] = {key: np.asarray(v) for key, v in rec.items() if v}
    return out


def _iae(controller: str, r_r: float, noisy: bool, choices: Choices, cache: dict,
         fig_3_6: bool = False) -> tuple[float, float]:
    # the run depends only on the choices that reach this controller: share the others'
    relevant = dataclasses.replace(
        choices, **{name: getattr(NOMINAL, name) for name, who in _AFFECTS.items()
                    if controller not in who})
    sigma = choices.noise if noisy else 0.0
    if not noisy:
        relevant = dataclasses.replace(relevant, noise=NOMINAL.noise)
    key = (controller, r_r, noisy, relevant, fig_3_6)
    if key not in cache:
        res = run(controller, reference(r_r, choices) if fig_3_6 else steps(r_r, choices), choices, sigma,
                  estimation_cache=cache.setdefault('estimation', {}))
        cache[key] = (res['iae'], res['peak_u_f'])
    return cache[key]


def _row(label, r_r, noisy, choices: Choices, cache: dict, fig_3_6: bool = False) -> dict:
    (aimc, pu_a), (aw, pu_aw), (mv, pu_mv) = (
        _iae(c, r_r, noisy, choices, cache, fig_3_6) for c in ('aimc', 'mvpc_aw', 'mvpc'))
    return {'iae': {'aimc': aimc, 'mvpc_aw': aw, 'mvpc': mv},
            'ratio': {'mvpc_aw': aw / aimc, 'mvpc': mv / aimc},
            'peak_u_f': {'aimc': pu_a, 'mvpc_aw': pu_aw, 'mvpc': pu_mv}}


def _finite(x) -> bool:
    if isinstance(x, dict):
        return all(_finite(v) for v in x.values())
    return math.isfinite(x)


def table_3_1(choices: Choices = NOMINAL, grid: dict | None = None) -> dict:
    """Table 3.1's simulation rows with `choices`, their spread over `grid` (default GRID,
    one choice at a time at its low and high value; {} for none) and the Fig. 3.7 run.

    Returns {'status': 'ok' | 'failed', 'reason': str, 'rows': [...], 'fig_3_7': {...},
    'choices': {...}, 'grid': {...}}; each row: label, r_r, noise, iae per controller, ratio
    (MVPC+AW, MVPC over AIMC), seed ratio, ours/seed, within (10 %), spread (min, max of each
    ratio over the grid, nominal included), the grid point of each extreme and 'by_choice'
    {choice: [(value, ratio), ...]}, and
    'fig_3_6_reference': the ratios on Fig. 3.6's ramped square wave with its sine (the
    reading before 2026-11-28), for information."""
    grid = GRID if grid is None else grid
    try:
        cache: dict = {}
        rows = []
        for label, r_r, noisy, seed_aw, seed_mv in SEED_ROWS:
            row = _row(label, r_r, noisy, choices, cache)
            seed = {'mvpc_aw': seed_aw, 'mvpc': seed_mv}
            vs = {c: row['ratio'][c] / seed[c] for c in seed}
            spread = {c: [row['ratio'][c], row['ratio'][c], 'nominal', 'nominal'] for c in seed}
            by_choice = {c: {} for c in seed}
            for name, values in grid.items():
                if name == 'noise' and not noisy:
                    continue
                for value in values:
                    alt = _row(label, r_r, noisy, dataclasses.replace(choices, **{name: value}),
                               cache)
                    for c in seed:
                        v = alt['ratio'][c]
                        by_choice[c].setdefault(name, []).append((value, v))
                        s = spread[c]
                        if v < s[0]:
                            s[0], s[2] = v, f'{name}={value:g}'
                        if v > s[1]:
                            s[1], s[3] = v, f'{name}={value:g}'
            # Fig. 3.6's reference, the reading before 2026-11-28 (information, not in the spread)
            ramped = _row(label, r_r, noisy, choices, cache, fig_3_6=True)
            rows.append({'label': label, 'r_r': r_r, 'noise': choices.noise if noisy else 0.0,
                         **row, 'seed': seed, 'ours_over_seed': vs,
                         'fig_3_6_reference': ramped['ratio'],
                         'within': {c: abs(vs[c] - 1.0) <= TOLERANCE for c in seed},
                         'spread': {c: {'min': s[0], 'max': s[1], 'min_at': s[2],
                                        'max_at': s[3], 'by_choice': by_choice[c]}
                                    for c, s in spread.items()}})
        fig = fig_3_7(choices)
        result = {'status': 'ok', 'reason': '', 'rows': rows, 'fig_3_7': fig,
                  'choices': dataclasses.asdict(choices),
                  'grid': {k: list(v) for k, v in grid.items()}}
        bad = [r['label'] for r in rows if not (_finite(r['iae']) and _finite(r['ratio']))]
        if bad:
            result.update(status='failed', reason=f'non-finite IAE in {", ".join(bad)}')
        elif fig['status'] != 'ok':
            result.update(status='failed', reason=f"Fig. 3.7 run: {fig['reason']}")
        return result
    except Exception as exc:      # the API reports, it does not raise
        return {'status': 'failed', 'reason': f'{type(exc).__name__}: {exc}', 'rows': [],
                'fig_3_7': {}, 'choices': dataclasses.asdict(choices), 'grid': {}}


def fig_3_7(choices: Choices = NOMINAL, tol: float = FIG37_TOL) -> dict:
    """The adaptation run of Fig. 3.7: square wave + sine (no ramp), r_r = FIG37_R, the process
    gain of H_p^f times 1.5 at 8 s and times 0.4 at 16 s (seed 004 §3.3; "decreasing by 60 %"
    read as 60 % of the gain at that time: 2 -> 3 -> 1.2). The RLS's gain estimate is
    g^ = b^_f/(h k_c k_p) (closed loop b = h k_c k_p g, Eq. 3.17).

    Returns per segment the true gain factor, the estimate at the segment's end, the relative
    error there, and the settling time: the first time after the step from which the
    estimate stays within `tol` of the new gain to the segment's end (None if never); the
    peak |u_f|/u_sat (the DRG keeps <= 1 when the model is right) and the smallest alpha."""
    try:
        pc = PlantConfig()
        h = pc.h
        r = reference(FIG37_R, choices, ramp=False)
        res = run('aimc', r, choices, gain_steps=FIG37_STEPS, record=True)
        sig = res['signals']
        g_hat = sig['b_f'] / (h * pc.kc_f * pc.kp_f)
        bounds = [0.0] + [t for t, _ in FIG37_STEPS] + [choices.duration]
        factor = 1.0
        segments = []
        for i in range(len(bounds) - 1):
            if i > 0:
                factor *= FIG37_STEPS[i - 1][1]
            k0, k1 = int(round(bounds[i] / h)), int(round(bounds[i + 1] / h))
            rel = np.abs(g_hat[k0:k1] - factor) / factor
            outside = np.nonzero(rel > tol)[0]
            if len(outside) == 0:
                settle = 0.0
            elif outside[-1] == len(rel) - 1:
                settle = None
            else:
                settle = (outside[-1] + 1) * h
            u = np.abs(sig['u_f'][k0:k1]) / pc.u_sat
            segments.append({'start': bounds[i], 'end': bounds[i + 1], 'gain_factor': factor,
                             'estimate_end': float(g_hat[k1 - 1]),
                             'error_end': float(rel[-1]), 'settle_time': settle,
                             'peak_u_over_sat': float(u.max()),
                             'min_alpha': float(sig['alpha'][k0:k1].min())})
        ok = all(s['settle_time'] is not None for s in segments)
        return {'status': 'ok' if ok else 'failed',
                'reason': '' if ok else 'the gain estimate did not settle within '
                                        f'{tol:.0%} in every segment',
                'r_r': FIG37_R, 'tolerance': tol, 'segments': segments, 'iae': res['iae']}
    except Exception as exc:
        return {'status': 'failed', 'reason': f'{type(exc).__name__}: {exc}', 'segments': []}


def format_table(result: dict) -> str:
    """seed | ours | ours/seed | spread per ratio, then the Fig. 3.7 summary."""
    if result.get('status') != 'ok' and not result.get('rows'):
        return f"Table 3.1: {result.get('status')}: {result.get('reason')}"
    lines = ['Table 3.1 (seed 004), simulation rows: IAE (3.19) normalized by AIMC',
             f"{'row':26s} {'ctrl':8s} {'seed':>6s} {'ours':>6s} {'ours/seed':>9s}  "
             f"{'spread (min..max over grid)':30s}"]
    names = {'mvpc_aw': 'MVPC+AW', 'mvpc': 'MVPC'}
    for row in result['rows']:
        for c in ('mvpc_aw', 'mvpc'):
            s = row['spread'][c]
            flag = '' if row['within'][c] else '  >10%'
            lines.append(f"{row['label']:26s} {names[c]:8s} {row['seed'][c]:6.3f} "
                         f"{row['ratio'][c]:6.3f} {row['ours_over_seed'][c]:9.3f}  "
                         f"{s['min']:.3f}..{s['max']:.3f} ({s['min_at']} .. {s['max_at']})"
                         f"{flag}")
        iae = row['iae']
        lines.append(f"{'':26s} IAE: AIMC {iae['aimc']:.3f}, MVPC+AW {iae['mvpc_aw']:.3f}, "
                     f"MVPC {iae['mvpc']:.3f}; peak |u_f|: "
                     + ', '.join(f"{k} {v:.1f}" for k, v in row['peak_u_f'].items()))
        so = row['fig_3_6_reference']
        lines.append(f"{'':26s} on Fig. 3.6's ramped square wave with its sine instead: MVPC+AW "
                     f"{so['mvpc_aw']:.3f}, MVPC {so['mvpc']:.3f}")
    fig = result.get('fig_3_7') or {}
    if fig.get('segments'):
        lines.append(f"Fig. 3.7 (r_r = {fig['r_r']:g}): RLS estimate of the H_p^f gain factor")
        for s in fig['segments']:
            st = 'never' if s['settle_time'] is None else f"{s['settle_time']:.2f} s"
            lines.append(f"  {s['start']:4.0f}-{s['end']:4.0f} s: true {s['gain_factor']:.3f}, "
                         f"estimate at end {s['estimate_end']:.3f} "
                         f"(error {s['error_end']:.2%}), within {fig['tolerance']:.0%} after "
                         f"{st}; peak |u_f|/u_sat {s['peak_u_over_sat']:.2f}, "
                         f"min alpha {s['min_alpha']:.2f}")
    lines.append(f"status: {result['status']}{': ' + result['reason'] if result['reason'] else ''}")
    return '\n'.join(lines)


def plots(result: dict, directory) -> list[str]:
    """midrange.png: the AIMC on Fig. 3.6's ramped reference at row 2's r_r = 5 (the relative
    position, both loops' positions; Fig. 3.6 without its disturbance) and the RLS's gain estimate through
    the gain steps of Fig. 3.7 beside the true gain and |u_f| / u_sat. Reruns both with
    the result's choices (the same numbers)."""
    if result.get('status') != 'ok':
        return []
    from machine_ctrl.experiments.seed_rows import save_figure, two_panels
    choices = Choices(**result['choices'])
    pc = PlantConfig()
    r = reference(5.0, choices)
    sig = run('aimc', r, choices, record=True)['signals']
    t = np.arange(len(r)) * pc.h
    plt, fig, (left, right) = two_panels(directory)
    for values, label in ((r, 'r_r'), (sig['y_r'], 'y_r'), (sig['y_f'], 'y_f (fine, mid-ranged)'),
                          (sig['y_s'], 'y_s (slow)')):
        left.plot(t, values, lw=0.8, label=label)
    left.set_xlabel('time [s]')
    left.set_ylabel('position (Fig. 3.6, AIMC, r_r = 5)')
    adapted = run('aimc', reference(FIG37_R, choices, ramp=False), choices, gain_steps=FIG37_STEPS,
                  record=True)['signals']
    true = np.ones(len(t))
    for at, factor in FIG37_STEPS:
        true[int(round(at / pc.h)):] *= factor
    right.plot(t, adapted['b_f'] / (pc.h * pc.kc_f * pc.kp_f), lw=0.8, label='RLS gain estimate')
    right.plot(t, true, 'k--', lw=0.8, label='true gain factor')
    right.plot(t, np.abs(adapted['u_f']) / pc.u_sat, lw=0.5, alpha=0.6, label='|u_f| / u_sat')
    right.set_xlabel('time [s]')
    right.set_ylabel('Fig. 3.7: gain steps +50 % at 8 s, -60 % at 16 s')
    for ax in (left, right):
        ax.legend(fontsize=8)
    return [save_figure(plt, fig, directory, 'midrange.png')]
