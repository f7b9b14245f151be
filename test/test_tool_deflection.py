"""The structure's deflection under the milling force (hw_sim/tool_deflection.py, issue [4/8]:
"a Cartesian stiffness model deflected by a milling process force model"): expected values
by hand from the model's equations (Sörnmo Eqs. 4.1, 5.3-5.4), not from the code."""
import dataclasses
import math

import numpy as np
import pytest

from hw_sim.robot_compliance import MillingConfig
from hw_sim.simulator import MachineSimulator, true_geometry
from hw_sim.tool_deflection import ToolDeflection, deflections, engagement
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.model.config import load_machine
from machine_ctrl.recording import analysis
from test_config import edited_machine

PERIOD = 1.0e-4
X_IN = -0.05              # m, along the face: inside robot_piezo's block (-103 ... -3 mm) and its ramps


@pytest.fixture(scope='module')
def compliance(robot_piezo):
    return robot_piezo.simulation.tool_compliance


@pytest.fixture(scope='module')
def smooth(compliance):
    """The machine's compliance without the tooth ripple and the per-tooth variation."""
    return dataclasses.replace(compliance, milling=dataclasses.replace(compliance.milling, ripple=0.0, variation=0.0))


def feed_along_x(model: ToolDeflection, speed: float, steps: int, x0: float = 0.0, z: float = 0.0):
    """Move the rigid tip along x at `speed` for `steps` periods; the deflection per step."""
    out = []
    for k in range(1, steps + 1):
        model.step((x0 + speed * k * PERIOD, 0.0, z))
        out.append(model.deflection)
    return np.array(out)


def test_the_machine_cuts_as_section_2_7_with_the_mechanistic_removal(compliance):
    seed = MillingConfig(feed=7.5e-3, depth=1e-3, spindle_speed=28000.0)     # section 2.7's cut
    assert compliance.milling.removal == pytest.approx(seed.removal, rel=1e-4)
    assert compliance.milling.tooth_frequency == pytest.approx(2 * 28000 / 60)
    assert compliance.milling.interaction_stiffness == 143e3                  # section 5.5


def test_a_steady_cut_deflects_the_tool_by_d_f_v_over_k(smooth):
    model = ToolDeflection(smooth, PERIOD, 1, (X_IN, 0.0, 0.0))
    v, steps = 7.5e-3, 40000                  # 4 s: the 9 Hz mode (zeta 0.05) has rung down to e^-11
    d = feed_along_x(model, v, steps, x0=X_IN)
    x = X_IN + v * steps * PERIOD             # -20 mm: k(x) = 150 + 5 sin(-2 pi 0.2) N/mm
    k = 150e3 + 5e3 * math.sin(2 * math.pi * x / 0.1)
    assert model.force == pytest.approx(2762.1 * v, rel=1e-9)        # Eq. (5.4): f = D_f v
    assert d[-1] == pytest.approx(2762.1 * v / k, rel=1e-3)          # Eq. (4.1): f = k d (k drifts slowly)


def test_the_mode_rings_at_the_robots_eigenfrequency(smooth):
    model = ToolDeflection(smooth, PERIOD, 1, (X_IN, 0.0, 0.0))
    d = feed_along_x(model, 7.5e-3, 20000, x0=X_IN)   # the cut starts at once: a step of force, D_f/K_f = 19 ms
    x = X_IN + 7.5e-3 * 0.055                 # where the peak comes (half a period in): k(x) = 150 + 5 sin(...)
    static = 2762.1 * 7.5e-3 / (150e3 + 5e3 * math.sin(2 * math.pi * x / 0.1))
    # the overshoot of a lightly damped mode over a step, e^(-pi zeta / sqrt(1 - zeta^2)), times
    # the first-order lag's gain at the mode, 1 / sqrt(1 + (w tau)^2), tau = D_f / K_f
    w, tau = 2 * math.pi * 9.0, 2762.1 / 143e3
    overshoot = math.exp(-math.pi * 0.05 / math.sqrt(1 - 0.05 ** 2)) / math.sqrt(1 + (w * tau) ** 2)
    assert d.max() / static == pytest.approx(1 + overshoot, rel=0.03)
    crossings = np.flatnonzero(np.diff(np.sign(d - static)) != 0)
    period = 2 * np.mean(np.diff(crossings[1:9])) * PERIOD
    assert 1 / period == pytest.approx(9.0 * math.sqrt(1 - 0.05 ** 2), rel=0.01)


def test_no_force_at_rest_above_the_cut_or_off_the_block_and_half_at_its_edge(compliance):
    milling = compliance.milling
    x = sum(milling.block_x) / 2                                               # inside the block
    assert engagement(milling, x, 0.0, 0.0) == 1.0
    assert engagement(milling, x, 0.0, milling.depth) == 0.0                   # above the layer
    assert engagement(milling, x, 0.0, -milling.depth) == 2.0                  # twice as deep
    assert engagement(milling, x, 0.0, milling.depth / 4) == 0.75
    edge, r = milling.block_x[1], milling.tool_radius
    assert engagement(milling, edge, 0.0, 0.0) == pytest.approx(0.5)           # centre on the edge
    assert engagement(milling, edge + r, 0.0, 0.0) == 0.0                      # just touching from outside
    assert engagement(milling, edge - r, 0.0, 0.0) == 1.0
    assert engagement(milling, x, milling.block_y[0] - 2 * r, 0.0) == 0.0
    model = ToolDeflection(compliance, PERIOD, 1, (x, 0.0, 0.0))
    assert not feed_along_x(model, 0.0, 1000, x0=x).any() and model.force == 0.0    # no feed, no chip
    model = ToolDeflection(compliance, PERIOD, 1, (x, 0.0, 0.0))
    assert not feed_along_x(model, 7.5e-3, 1000, x0=x, z=2 * milling.depth).any()    # cutting air
    model = ToolDeflection(compliance, PERIOD, 1, (0.0, 0.0, 0.0))
    assert not feed_along_x(model, 7.5e-3, 1000).any()                          # off the block: home


def in_the_block(machine):
    """An initial position with the tool ~10 mm inside the block (j5 moves it along -x at home)."""
    q = list(machine.home)
    q[4] += 0.054
    return q


@pytest.fixture(scope='module')
def feed_run(robot_piezo):
    """hw_sim's simulator turning the robot's j1 at a steady 1e-3 rad/s (the tool tip moves
    along the face at ~1 mm/s) for 0.5 s, in the block."""
    start = in_the_block(robot_piezo)
    sim = MachineSimulator(robot_piezo, initial_position=start)
    true, measured, deflection = [sim.true_position], [sim.measurement.position], [sim.deflection]
    for k in range(1, 5001):
        command = list(start)
        command[0] += 1e-3 * k * PERIOD
        sim.step(command)
        true.append(sim.true_position)
        measured.append(sim.measurement.position)
        deflection.append(sim.deflection)
    return np.array(true), np.array(measured), np.array(deflection)


def test_hw_sim_deflects_the_true_tip_the_encoders_do_not_see_it_and_a_replay_matches_it_bit_for_bit(robot_piezo,
                                                                                                   feed_run):
    true, measured, deflection = feed_run
    assert deflection.max() > 1e-6                              # the cut loads the arm
    without = dataclasses.replace(robot_piezo, simulation=dataclasses.replace(robot_piezo.simulation,
                                                                              tool_compliance=None))
    start = in_the_block(robot_piezo)
    sim = MachineSimulator(without, initial_position=start)
    for k in range(1, 5001):
        command = list(start)
        command[0] += 1e-3 * k * PERIOD
        sim.step(command)
    assert sim.measurement.position == tuple(measured[-1])      # the same encoders, to the bit
    replay = deflections(robot_piezo, true_geometry(robot_piezo), true)
    assert np.array_equal(replay, deflection)


def test_a_fault_freezes_the_deflection_and_a_reset_starts_it_afresh(robot_piezo):
    start = in_the_block(robot_piezo)
    sim = MachineSimulator(robot_piezo, initial_position=start)
    command = list(start)
    for k in range(1, 300):
        command[0] = start[0] + 1e-3 * k * PERIOD
        sim.step(command)
    held = sim.deflection
    assert held != 0.0
    sim.step([math.nan] * len(command))
    assert sim.fault and sim.deflection == held
    sim.step(command)
    assert sim.deflection == held
    sim.reset()
    assert sim.fault is None and sim.deflection == 0.0


def test_analyze_reports_the_error_only_the_ground_truth_sees(robot_piezo):
    """A Run whose measured positions follow the reference exactly and whose true tool tips sit
    40 um off it along z: tracking 0, true_tracking 40 um (at the steps with a truth)."""
    q = np.tile(np.array(robot_piezo.home), (20, 1))
    steps = np.arange(20)
    tip = true_geometry(robot_piezo)(tuple(robot_piezo.home))[:3, 3]
    true_tip = {k: (tip[0], tip[1], tip[2] + 40e-6) for k in range(0, 20, 10)}
    run = analysis.Run(robot_piezo, steps, q, q, 'test', {}, true_tip)
    result = analysis.analyse(run)
    assert result['tool_tip']['tracking']['max'] == 0.0
    assert result['tool_tip']['true_tracking']['mean'] == pytest.approx(40e-6, rel=1e-6)
    assert 'true_tracking' in analysis.table([result], [robot_piezo])
    result = analysis.analyse(analysis.Run(robot_piezo, steps, q, q, 'test'))
    assert 'true_tracking' not in result['tool_tip']


@pytest.mark.parametrize('edit, reason', [
    (('eigenfrequency: 9.0 ', 'eigenfrequency: 90.0 '), r'tool_compliance: eigenfrequency 90 Hz is too high'),
    (('block_x: [-0.103, -0.003]', 'block_x: [-0.003, -0.103]'), r'milling\.block_x: \[-0\.003, -0\.103\] is empty'),
    (('stiffness_variation: 5.0e+3', 'stiffness_variation: 150.0e+3'), r'stiffness_variation 150000 must be below'),
    (('      depth: 1.0e-3 ', '      depth: -1.0e-3 '), r'tool_compliance\.milling\.depth: must be > 0'),
    (('      tool_radius: 3.0e-3 ', '      # no radius '), r'tool_compliance\.milling\.tool_radius: missing'),
])
def test_a_bad_compliance_is_refused_with_the_reason(tmp_path, edit, reason):
    with pytest.raises(ConfigError, match=reason):
        load_machine(edited_machine(tmp_path, edit, name='robot_piezo'))
