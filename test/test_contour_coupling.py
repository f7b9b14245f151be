"""The cross-coupled contour control (machine_ctrl/control/contour_coupling.py; issue [7/8]
part 2): it corrects the error across the path and leaves the error along it, through the
axes Koren's coupling gains name; it uses only valid estimates and fades without them; it
switches at run time and takes new gains without a step; and on trt_5axis's Eq. (35) path it
halves the tool-tip contour error (experiment contour, test_contour.py)."""
import dataclasses
import math

import numpy as np
import pytest

from hw_sim.offline import run
from machine_ctrl.control.contour_coupling import ContourCoupling, CouplingStatus
from machine_ctrl.model.config import ContourChannelGains
from machine_ctrl.model.reference import Reference
from trajectory.contours import circle

SPEED = 0.01          # m/s along x_c
ROWS = 6000           # 0.6 s at 10 kHz: the estimate of a middle step sees its whole window


def line(machine, rows=ROWS) -> Reference:
    """x_c at SPEED from home, every other axis at home: a straight tool path."""
    q = np.tile(np.asarray(machine.home, float), (rows, 1))
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    x = machine.axis_names.index('x_c')
    q[:, x] += SPEED * machine.control_period * np.arange(rows)
    qd[:, x] = SPEED
    return Reference(machine.axis_names, machine.control_period, q, qd, qdd)


def coupling_on(machine, reference, config=None) -> ContourCoupling:
    coupling = ContourCoupling(machine, config, enabled=True)
    coupling.add_reference(0, reference.position, reference.velocity, reference.acceleration)
    return coupling


def displaced(machine, reference, step, **offsets):
    q = reference.position[step].copy()
    for axis, value in offsets.items():
        q[machine.axis_names.index(axis)] += value
    return q


def correction(machine, coupling, result, axis):
    return result.corrections[coupling.axes.index(axis)]


def decay_of(machine):
    """exp(-T/fade): the factor by which a channel's proportional weight rises (1 - (1 - w) d)
    with valid estimates and falls (w d) without, per step."""
    return math.exp(-machine.control_period / machine.contour_control.fade)


def test_the_error_across_the_path_is_corrected_and_the_error_along_it_is_not(micromill):
    """Koren's CCC on a line along x: a lag of 3 um along the path (x_c behind) is no contour
    error; 0.2 um of y_f across it is, and y_f's reference moves back by (k_p w + k_i T) times
    it, w = 1 - d^2 at the second step of a fresh coupling; x_f and z_f stay."""
    reference = line(micromill)
    coupling = coupling_on(micromill, reference)
    gains, period, d = micromill.contour_control.tool_tip, micromill.control_period, decay_of(micromill)
    k = ROWS // 2
    coupling.step(k - 1, reference.position[k - 1])             # at the path: nothing to correct
    result = coupling.step(k, displaced(micromill, reference, k, x_c=-3e-6, y_f=0.2e-6))
    assert result.status is CouplingStatus.ACTIVE and result.reason == ''
    assert correction(micromill, coupling, result, 'y_f') == pytest.approx(
        -(gains.proportional * (1 - d * d) + gains.integral * period) * 0.2e-6, rel=1e-6, abs=0)
    assert abs(correction(micromill, coupling, result, 'x_f')) < 1e-15
    assert abs(correction(micromill, coupling, result, 'z_f')) < 1e-15


def test_the_integral_adds_k_i_T_eps_per_step_and_new_gains_take_over_without_a_step(micromill):
    """A constant contour error eps from a fresh coupling: step n gives k_p w_n eps + the
    integral, w_n = 1 - d^n. A new k_i changes only what is added from then on; a new k_p moves
    the correction by (Delta k_p) w eps."""
    reference = line(micromill)
    coupling = coupling_on(micromill, reference)
    gains, period, eps, d = micromill.contour_control.tool_tip, micromill.control_period, 0.2e-6, decay_of(micromill)
    kp = gains.proportional

    def y_f(k):
        return -correction(micromill, coupling, coupling.step(k, displaced(micromill, reference, k, y_f=eps)), 'y_f')

    def w(n):
        return 1 - d ** n

    k = ROWS // 2
    first, second = y_f(k), y_f(k + 1)
    assert first == pytest.approx((kp * w(1) + gains.integral * period) * eps, rel=1e-6, abs=0)
    assert second - first == pytest.approx((kp * (w(2) - w(1)) + gains.integral * period) * eps, rel=1e-6, abs=0)
    coupling.retune(dataclasses.replace(micromill.contour_control, tool_tip=dataclasses.replace(gains, integral=500.0)))
    third = y_f(k + 2)
    assert third - second == pytest.approx((kp * (w(3) - w(2)) + 500.0 * period) * eps, rel=1e-6, abs=0)   # integral kept
    coupling.retune(dataclasses.replace(coupling.config, tool_tip=ContourChannelGains(3.0, 500.0)))
    fourth = y_f(k + 3)
    assert fourth - third == pytest.approx((3.0 * w(4) - kp * w(3) + 500.0 * period) * eps, rel=1e-6, abs=0)


def test_without_a_valid_estimate_the_correction_fades_and_resumes_from_there(micromill):
    """No reference row for the step (an estimate cannot be made): the correction decays by
    exp(-T/fade) per step, the status says why; with the rows back it is corrected again."""
    reference = line(micromill)
    coupling = coupling_on(micromill, reference)
    decay = decay_of(micromill)
    k = ROWS // 2
    before = coupling.step(k, displaced(micromill, reference, k, y_f=0.2e-6)).corrections
    q = displaced(micromill, reference, k, y_f=0.2e-6)
    faded = coupling.step(ROWS + 10, q)                     # beyond the reference's end
    assert faded.status is CouplingStatus.FADING and 'no reference row for step' in faded.reason
    assert np.allclose(faded.corrections, np.array(before) * decay, rtol=1e-9, atol=1e-18)
    again = coupling.step(ROWS + 11, q)
    assert np.allclose(again.corrections, np.array(before) * decay ** 2, rtol=1e-9, atol=1e-18)
    assert coupling.invalid_steps['tool_tip'] == 0          # no estimate was made, none was invalid


def test_an_invalid_estimate_is_not_used(micromill):
    """Behind the start of a path that has never moved (the tool short of where it begins),
    the estimate is marked invalid ('start': its closest point is the start point, which no
    tangent line gives): the channel fades instead of taking it."""
    reference = line(micromill)
    coupling = coupling_on(micromill, reference)
    result = coupling.step(0, displaced(micromill, reference, 0, x_c=-5e-6, y_f=0.3e-6))
    assert result.status is CouplingStatus.FADING, result
    assert 'tool tip estimate invalid' in result.reason
    assert coupling.invalid_steps['tool_tip'] == 1
    assert result.corrections == (0.0, 0.0, 0.0)


def test_switched_off_it_fades_out_then_costs_nothing_and_switched_on_fades_in_from_zero(micromill):
    """Off: the correction decays by d per step until it is below 1 fm, then OFF (zeros, nothing
    computed). On again under the same contour error: it starts from zero, the first step's
    correction being (k_p (1 - d) + k_i T) eps, no step of k_p eps."""
    reference = line(micromill)
    coupling = coupling_on(micromill, reference)
    decay = decay_of(micromill)
    k, eps = 1000, 0.2e-6
    on = coupling.step(k, displaced(micromill, reference, k, y_f=eps))
    coupling.set_enabled(False)
    previous, k = np.array(on.corrections), k + 1
    while True:
        result = coupling.step(k, displaced(micromill, reference, k, y_f=eps))
        if result.status is CouplingStatus.OFF:
            break
        assert result.status is CouplingStatus.FADING and result.reason == 'switched off'
        assert np.allclose(result.corrections, previous * decay, rtol=1e-9, atol=1e-18)
        previous, k = np.array(result.corrections), k + 1
    assert result.corrections == (0.0, 0.0, 0.0)
    assert k - 1000 < 60 * micromill.contour_control.fade / micromill.control_period     # 35 fades to 1 fm
    coupling.set_enabled(True)
    gains = micromill.contour_control.tool_tip
    result = coupling.step(k, displaced(micromill, reference, k, y_f=eps))
    assert result.status is CouplingStatus.ACTIVE
    assert -correction(micromill, coupling, result, 'y_f') == pytest.approx(
        (gains.proportional * (1 - decay) + gains.integral * micromill.control_period) * eps, rel=1e-5, abs=0)


def test_off_and_faded_out_its_steps_equal_those_that_ask_quiet_every_step(micromill):
    """Once off and faded out the coupling no longer asks `quiet` (numpy) at each step: its
    channels cannot change until it is switched on. On, off (fading, then OFF for a while),
    on again and off again, every step equals a twin's that is made to ask every step."""
    reference = line(micromill)
    kept, twin = coupling_on(micromill, reference), coupling_on(micromill, reference)
    switches = {1000: False, 5000: True, 5100: False, 5200: True}        # ~3500 steps to fade out
    statuses = set()
    for k in range(900, 5300):
        for coupling in (kept, twin):
            if k in switches:
                coupling.set_enabled(switches[k])
        twin._idle = False
        q = displaced(micromill, reference, k, y_f=0.2e-6)
        a, b = kept.step(k, q), twin.step(k, q)
        assert (a.corrections, a.status, a.reason) == (b.corrections, b.status, b.reason)
        assert (kept.reference.first, kept.trajectory.first) == (twin.reference.first, twin.trajectory.first)
        statuses.add(a.status)
    assert statuses == set(CouplingStatus) and kept.enabled


@pytest.mark.parametrize('change, reason', [
    (dict(axes=('x_f', 'y_f')), 'axes: fixed while running'),
    (dict(estimator='basic'), 'estimator: fixed while running'),
    (dict(fade=0.0), 'fade: must be > 0, got 0'),
    (dict(tool_tip=ContourChannelGains(-1.0, 10.0)), 'tool_tip.proportional: must be >= 0, got -1'),
    (dict(tool_tip=ContourChannelGains(1.0, math.nan)), 'tool_tip.integral: must be finite, got nan'),
    (dict(orientation=ContourChannelGains(1.0, 10.0)), 'orientation: the channel cannot be added or removed'),
])
def test_a_refused_retune_says_why_and_changes_nothing(micromill, change, reason):
    coupling = ContourCoupling(micromill)
    config = coupling.config
    assert reason in coupling.retune_problem(dataclasses.replace(config, **change))
    with pytest.raises(ValueError, match=reason.split(':')[0]):
        coupling.retune(dataclasses.replace(config, **change))
    assert coupling.config is config
    assert 'must be ContourControlConfig' in coupling.retune_problem(config.tool_tip)


def test_a_machine_without_contour_control_cannot_have_one(fts_lathe):
    with pytest.raises(ValueError, match='fts_lathe: no contour_control section'):
        ContourCoupling(fts_lathe)


def test_the_coupled_offline_run_is_reproducible_bit_for_bit_and_moves_only_the_fine_stage(micromill):
    """Two lock-step runs of the circle's start with the coupling: the same numbers; against
    the dual stage alone only the coupled axes' commands differ (z_f too: the table's noise
    has a z part) and nothing faults."""
    reference, _ = circle(micromill)
    runs = [run(micromill, reference, steps=3000, contour_control=True) for _ in range(2)]
    assert np.array_equal(runs[0].measured, runs[1].measured) and np.array_equal(runs[0].commands, runs[1].commands)
    assert runs[0].fault is None and runs[0].contour_invalid == runs[1].contour_invalid
    plain = run(micromill, reference, steps=3000)
    differs = [a for i, a in enumerate(micromill.axis_names)
               if not np.array_equal(plain.commands[:, i], runs[0].commands[:, i])]
    assert differs == ['x_f', 'y_f', 'z_f']


def test_a_step_waits_for_the_rows_its_estimate_reads(micromill):
    """On, step k's estimate reads the rows to the end of the 500-step block holding
    k + horizon (2000 steps at 10 kHz): has_rows_for says whether they are here, so a node
    waits for a lagging stream instead of estimating from fewer rows; off, nothing is needed."""
    coupling = ContourCoupling(micromill, enabled=True)
    n = len(micromill.axes)
    zeros = np.zeros((2500, n))
    coupling.add_reference(0, zeros, zeros, zeros)          # rows 0..2499
    assert coupling.has_rows_for(0) and coupling.has_rows_for(499)      # block end 2500
    assert not coupling.has_rows_for(500)                   # 500 + 2000 -> block end 3000
    coupling.add_reference(2500, zeros[:500], zeros[:500], zeros[:500])
    assert coupling.has_rows_for(999) and not coupling.has_rows_for(1000)
    coupling.set_enabled(False)
    assert coupling.has_rows_for(10_000)
