"""hw_sim/compiled_loop.py and hw_sim/python_random.py: the offline runner's compiled loop
gives what its Python loop gives, bit for bit, on every machine and option it covers,
faults included; where it does not cover a run, the Python loop runs."""
import random

import numpy as np
import pytest

from hw_sim import compiled_loop, python_random
from hw_sim.offline import run
from hw_sim.simulator import MachineSimulator
from machine_ctrl.control.dual_stage import DualStageCoupling
from machine_ctrl.control.servo import ServoGroup
from machine_ctrl.model.reference import Reference
from trajectory.contours import circle

ROWS = ('reference', 'measured', 'measured_velocity', 'effort', 'true', 'commands', 'offsets')


def assert_same_run(python, compiled):
    """Every row bit for bit (so -0.0 != 0.0; NaNs equal whatever their sign and payload,
    hw_sim/compiled_loop.py), the fault, the saturations; and each loop did run."""
    assert not python.compiled and compiled.compiled
    for name in ROWS:
        x, y = getattr(python, name), getattr(compiled, name)
        assert x.shape == y.shape, name
        differ = np.argwhere((x.view(np.int64) != y.view(np.int64)) & ~(np.isnan(x) & np.isnan(y)))
        assert not len(differ), f'{name}: first differing (step, column) {differ[0].tolist()}'
    assert (python.fault, python.saturations, python.offset_axes) == (compiled.fault, compiled.saturations,
                                                                    compiled.offset_axes)


@pytest.mark.parametrize('seed', ['7:x_c:actuator', '7:z_f', 12345])
def test_streams_draw_what_random_random_draws(seed):
    stream = random.Random(seed)
    stream.gauss(0.0, 1.0)                          # a kept second value to start from
    twin = random.Random()
    twin.setstate(stream.getstate())
    words, index, spare, has_spare = python_random.pack([random.Random(0), stream])
    sigmas = [1.0, 1e-8, 0.5, 3.0] * 25000          # 100,000 draws: 50,000 angles' cos and sin (sincos)
    drawn = [python_random.gauss(words, index, spare, has_spare, 1, s) for s in sigmas]
    assert drawn == [twin.gauss(0.0, s) for s in sigmas]
    assert [python_random.uniform(words, index, 1) for _ in range(700)] == [twin.random() for _ in range(700)]


def _sine(machine, axis: str, amplitude: float, steps: int) -> Reference:
    """`axis` on a 20 Hz sine about home, the other axes at home."""
    t = np.arange(steps) * machine.control_period
    w = 2.0 * np.pi * 20.0
    position = np.tile(np.asarray(machine.home, float), (steps, 1))
    velocity, acceleration = np.zeros_like(position), np.zeros_like(position)
    i = machine.axis_names.index(axis)
    position[:, i] += amplitude * np.sin(w * t)
    velocity[:, i] = amplitude * w * np.cos(w * t)
    acceleration[:, i] = -amplitude * w * w * np.sin(w * t)
    return Reference(machine.axis_names, machine.control_period, position, velocity, acceleration)


@pytest.mark.parametrize('options', [{}, {'dual_stage': False}, {'feedforward': False},
                                     {'laws': {'x_c': 'ppi', 'y_c': 'ppi', 'z_c': 'ppi'}}],
                         ids=['dual stage', 'coarse only', 'no feed-forward', 'p-pi'])
def test_micromill_circle_is_the_same_in_both_loops(micromill, options):
    circling, _ = circle(micromill)
    reference = Reference(circling.axis_names, circling.period, *(a[-4000:] for a in (
        circling.position, circling.velocity, circling.acceleration)))        # its last 0.4 s
    python = run(micromill, reference, steps=4500, compiled=False, **options)    # and 500 steps held
    assert python.fault is None
    assert_same_run(python, run(micromill, reference, steps=4500, **options))


@pytest.mark.parametrize('options', [{'steps': 3500}, {'steps': 2000, 'feedforward': False}],
                         ids=['held past the end', 'shorter, no feed-forward'])
def test_trt_is_the_same_in_both_loops(trt, options):
    reference = _sine(trt, trt.axis_names[0], 1e-3, 3000)
    assert_same_run(run(trt, reference, compiled=False, **options), run(trt, reference, **options))


def test_a_saturating_coupling_is_the_same_in_both_loops(micromill):
    """A coarse axis started 2 mm from its reference: the fine axis's total reference is
    clipped and slewed (DualStageCoupling), the count reported alike."""
    reference = _sine(micromill, 'x_c', 1e-3, 2000)
    start = list(reference.position[0])
    start[micromill.axis_names.index('x_c')] += 2e-3
    python = run(micromill, reference, initial_position=start, compiled=False)
    assert python.saturations > 0
    assert_same_run(python, run(micromill, reference, initial_position=start))


def test_faults_are_named_alike_and_hold_alike(micromill, trt):
    # stroke violations: x_f's reference outside its stroke, the coupling off (a linear
    # table); trt's x beyond its stroke (a friction axis)
    reference = _sine(micromill, 'x_f', 400e-6, 2000)
    python = run(micromill, reference, dual_stage=False, compiled=False)
    assert python.fault.startswith('stroke violation on x_f')
    assert_same_run(python, run(micromill, reference, dual_stage=False))
    i, (low, high) = trt.axis_names.index('x'), trt.axis('x').stroke
    steps = 3000
    position = np.tile(np.asarray(trt.home, float), (steps, 1))
    speed = 1.2 * (high - position[0, i]) / (steps * trt.control_period)     # past the end in 2.5 s of 3
    position[:, i] += speed * trt.control_period * np.arange(steps)
    velocity = np.zeros_like(position)
    velocity[:, i] = speed
    reference = Reference(trt.axis_names, trt.control_period, position, velocity, np.zeros_like(position))
    python = run(trt, reference, compiled=False)
    assert python.fault.startswith('stroke violation on x')
    assert_same_run(python, run(trt, reference))
    # a non-finite command: a reference the sliding-mode law overflows on
    position = np.tile(np.asarray(micromill.home, float), (300, 1))
    position[100:, 0] = 1e308
    huge = Reference(micromill.axis_names, micromill.control_period, position, np.zeros_like(position),
                     np.zeros_like(position))
    python = run(micromill, huge, compiled=False)
    assert python.fault == 'non-finite command for x_c'
    assert_same_run(python, run(micromill, huge))


def test_progress_is_reported_at_the_same_steps(trt):
    reference = _sine(trt, trt.axis_names[0], 1e-3, 25000)
    calls = {True: [], False: []}
    for compiled in calls:
        run(trt, reference, progress=lambda k, n, c=compiled: calls[c].append((k, n)), compiled=compiled)
    assert calls[True] == calls[False] == [(0, 25000), (10000, 25000), (20000, 25000)]


def test_what_it_does_not_cover_runs_in_the_python_loop(micromill, fts_lathe, robot_piezo):
    for machine in (fts_lathe, robot_piezo):        # a flexure stage with accelerometer, piezo stages
        simulator = MachineSimulator(machine)
        assert compiled_loop.pack(simulator, ServoGroup(machine, machine.axis_names),
                                  DualStageCoupling(machine)) is None
    simulator, coupling = MachineSimulator(micromill), DualStageCoupling(micromill)
    assert compiled_loop.pack(simulator, ServoGroup(micromill, micromill.axis_names), coupling) is not None
    switching = ServoGroup(micromill, micromill.axis_names)
    switching.set_feedforward(False)                 # a switch waiting for a rest
    mixed = ServoGroup(micromill, micromill.axis_names)
    mixed.servos[0].set_feedforward(False)           # one axis without feed-forward
    for servo in (switching, mixed):
        assert compiled_loop.pack(simulator, servo, coupling) is None
    reference = _sine(micromill, 'x_c', 1e-4, 50)
    assert run(micromill, reference).compiled
    assert not run(micromill, reference, compiled=False).compiled
    assert not run(micromill, reference, contour_control=True).compiled
    sine = _sine(fts_lathe, 'w', 1e-7, 50)
    assert not run(fts_lathe, sine, forces={'w': np.zeros(50)}).compiled
