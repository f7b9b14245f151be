"""The fourth machine, robot_piezo (issue [4/8]; Sörnmo seed 004): an ABB IRB 2400 holding the
workpiece and the 3-axis piezo micro manipulator carrying the tool. Checked without ROS:
its kinematics against the manufacturer's numbers, the two new drives (a joint closing its
own position loop, a piezo stage of modes) against their transfer functions, the two new
laws, the Cartesian coupling against the kinematics it cancels, its mid-ranging, bad configs
refused with the reason, and offline milling runs with the coupling on and off, and with and
without the mid-ranging."""
import dataclasses
import math
import random
from pathlib import Path

import numpy as np
import pytest

from hw_sim.offline_goal import run_goal
from hw_sim.simulator import make_plant, true_geometry
from hw_sim.tool_deflection import deflections
from machine_ctrl.control.dual_stage import DualStageCoupling
from machine_ctrl.control.lqg import LqgLaw
from machine_ctrl.control.registry import make_law
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.model.kinematics import Kinematics
from trajectory import toolpath

MACHINES = Path(__file__).resolve().parents[1] / 'config' / 'machines'


@pytest.fixture(scope='module')
def kin(robot_piezo):
    return Kinematics.from_config(robot_piezo)


def test_the_robot_has_the_irb2400s_geometry_and_the_tool_meets_the_workpiece_at_home(robot_piezo, kin):
    import pinocchio as pin
    zero = np.zeros(9)
    pin.forwardKinematics(kin.model, kin.data, kin.pin_configuration(zero))
    wrist = kin.data.oMi[kin.model.getJointId('j5')].translation
    # ABB IRB 2400: shoulder offset 0.100 + wrist 0.755 forward, 0.615 + 0.705 + 0.135 up
    assert wrist == pytest.approx([0.100 + 0.755, 0.0, 0.615 + 0.705 + 0.135], abs=1e-12)
    p, o = kin.forward(np.array(robot_piezo.home))
    assert p == pytest.approx([0, 0, 0], abs=1e-9) and o == pytest.approx([0, 0, 1], abs=1e-12)
    assert robot_piezo.planned_axes == ('j1', 'j2', 'j3', 'j4', 'j5', 'j6')
    assert robot_piezo.fine_axes == ('px', 'py', 'pz') and robot_piezo.dual_stage == ()
    jacobian = kin.jacobian(np.array(robot_piezo.home))[:3, 6:]
    assert jacobian == pytest.approx(np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]]), abs=1e-12)   # stage axes


def test_a_joint_closes_its_own_loop_overshoot_of_zeta_and_no_lag_on_a_ramp_with_the_lead(robot_piezo):
    axis, period = robot_piezo.axis('j2'), robot_piezo.control_period
    w, zeta = axis.plant.servo.omega, axis.plant.servo.zeta
    plant = make_plant(axis, period, 1, random.Random(0))
    out = []
    for _ in range(int(0.5 / period)):
        plant.step(1e-3)
        out.append(plant.position)
    overshoot = max(out) / 1e-3 - 1.0
    assert overshoot == pytest.approx(math.exp(-math.pi * zeta / math.sqrt(1 - zeta * zeta)), rel=1e-3)
    assert out[-1] == pytest.approx(1e-3, rel=1e-9)
    law = make_law(axis, period)
    assert law.gains.velocity_lead == pytest.approx(2 * zeta / w, rel=1e-12)
    plant = make_plant(axis, period, 1, random.Random(0))
    rate, steps = 0.05, int(1.0 / period)              # rad/s
    for k in range(steps):
        x_r = rate * k * period
        plant.step(law.step(x_r, rate, 0.0, plant.position, plant.velocity))
    # after the transient the loop's own lag is gone (the lead); what is left is the zero-order
    # hold's half period: the command of step k holds over [kT, (k+1)T]
    assert rate * steps * period - plant.position == pytest.approx(rate * period / 2, rel=1e-6)


def test_a_piezo_axis_has_unit_static_gain_and_its_resonance(robot_piezo):
    axis, period = robot_piezo.axis('py'), robot_piezo.control_period
    mode = axis.plant.modes[0]
    plant = make_plant(axis, period, 1, random.Random(0))
    t = np.arange(int(3.0 / period)) * period
    out = []
    for tk in t:
        out.append(plant.position)
        plant.step(1e-6 * math.sin(mode.omega * tk))
    assert max(np.abs(out[len(out) // 2:])) / 1e-6 == pytest.approx(1 / (2 * mode.zeta), rel=0.02)
    at = 1024 * axis.drive.command_resolution           # a command the DAC makes exactly
    plant = make_plant(axis, period, 1, random.Random(0), position=at)
    plant.step(at)
    assert plant.position == pytest.approx(at, rel=1e-12) and abs(plant.velocity) < 1e-12   # at rest there


def test_the_lqg_law_holds_each_piezo_axis_on_its_plant(robot_piezo):
    period = robot_piezo.control_period
    for name in robot_piezo.fine_axes:
        axis = robot_piezo.axis(name)
        law = make_law(axis, period)
        plant = make_plant(axis, period, 1, random.Random(0))
        out = []
        for _ in range(int(1.0 / period)):
            out.append(plant.position)
            plant.step(law.step(20e-6, 0.0, 0.0, plant.position, 0.0))
        out = np.array(out) / 20e-6
        assert abs(out[-2000:] - 1.0).max() < 0.02, name        # the last 0.2 s within 2 % of the step
        assert out.max() < 1.5, name                            # its modes damped
    with pytest.raises(ValueError, match=r'axis j1: the lqg law needs a piezo drive with drive\.modes'):
        LqgLaw.from_axis(robot_piezo.axis('px').control.lqg, robot_piezo.axis('j1'), period)


def test_the_lqg_designs_from_the_drives_model_not_from_the_plant(robot_piezo):
    """The law's model has the poles of drive.modes held at the control period, z = exp(s T)
    for s = -zeta w +- j w sqrt(1 - zeta^2) (and pz's real pole), which differ from the
    plant's: the controller meets a model error, as one designed from an identified model does."""
    period = robot_piezo.control_period

    def poles(modes, real_pole):
        s = [complex(-m.zeta * m.omega, sign * m.omega * math.sqrt(1 - m.zeta ** 2)) for m in modes for sign in (1, -1)]
        return np.sort_complex(np.exp(np.array(s + ([-real_pole] if real_pole else [])) * period))
    for name in ('px', 'py', 'pz'):
        axis = robot_piezo.axis(name)
        law = LqgLaw.from_axis(axis.control.lqg, axis, period)
        found = np.sort_complex(np.linalg.eigvals(law.controller.design.phi).astype(complex))
        np.testing.assert_allclose(found, poles(axis.drive.modes, axis.drive.real_pole), rtol=0, atol=1e-9)
        assert np.abs(found - poles(axis.plant.modes, axis.plant.real_pole)).max() > 1e-6, name


@pytest.fixture(scope='module')
def encoders_only(robot_piezo):
    """robot_piezo whose coupling reads the robot's deviation from its encoders (no tracker) and
    leaves the robot's reference alone (no mid-ranging)."""
    return dataclasses.replace(robot_piezo, cartesian_dual_stage=dataclasses.replace(
        robot_piezo.cartesian_dual_stage, tracker=None, midranging=None))


def test_the_cartesian_coupling_cancels_the_tool_deviation_of_the_robots_errors(encoders_only, kin):
    robot_piezo = encoders_only
    coupling = DualStageCoupling(robot_piezo)
    ref = np.array(robot_piezo.home)
    error = np.array([2e-5, -3e-5, 4e-5, 1e-5, -2e-5, 1e-5, 0, 0, 0])     # rad, the robot lagging
    pos = ref - error
    offsets = np.array(coupling.step(ref, pos).offsets)
    deviation = kin.forward(pos)[0] - kin.forward(ref)[0]
    compensated = pos.copy()
    compensated[6:] += offsets
    left = kin.forward(compensated)[0] - kin.forward(ref)[0]
    assert np.linalg.norm(deviation) > 20e-6                               # tens of um
    assert np.linalg.norm(left) < 1e-3 * np.linalg.norm(deviation)          # second order only
    coupling.enabled = False
    assert coupling.step(ref, pos).offsets == (0.0, 0.0, 0.0)


def test_with_the_tracker_the_stage_cancels_what_the_tracker_sees_the_deflection_too(robot_piezo, kin):
    """The tracker reads the robot's tool tip (stage at home) with the arm's deflection: the
    stage's offsets put the deflected tool tip back on the reference. px moves the tool along
    the workpiece's z (J_fine is a signed permutation at home), so a deflection d along z
    alone is cancelled by px = -d exactly."""
    coupling = DualStageCoupling(robot_piezo)
    assert coupling.uses_tracker
    ref = np.array(robot_piezo.home)
    d = 100e-6
    tip = kin.forward(ref)[0]
    offsets = coupling.step(ref, ref, tuple(tip + [0.0, 0.0, d])).offsets[:3]      # then the mid-ranging's
    assert offsets[0] == pytest.approx(-d, abs=1e-12) and max(map(abs, offsets[1:])) < 1e-12
    error = np.array([2e-5, -3e-5, 4e-5, 1e-5, -2e-5, 1e-5, 0, 0, 0])     # rad, the robot lagging, too
    pos = ref - error
    offsets = np.array(DualStageCoupling(robot_piezo).step(ref, pos, tuple(kin.forward(pos)[0] + [0.0, 0.0, d])).offsets)
    offsets = offsets[:3]
    compensated = pos.copy()
    compensated[6:] += offsets
    left = kin.forward(compensated)[0] + [0.0, 0.0, d] - kin.forward(ref)[0]
    assert np.linalg.norm(left) < 1e-3 * d                                  # second order only
    with pytest.raises(ValueError, match=r'measures the deviation with a tracker: needs its reading'):
        DualStageCoupling(robot_piezo).step(ref, pos)


def test_the_coupling_follows_the_jacobian_along_the_path_and_a_reset_one_is_a_fresh_one(encoders_only):
    """J is evaluated again once the reference has moved more than JACOBIAN_STEP: stepped
    from home to a pose 0.1 rad away, the coupling gives what a fresh one gives there."""
    robot_piezo = encoders_only
    home = np.array(robot_piezo.home)
    moved = home + np.array([0.1, -0.05, 0.08, 0.1, 0.05, 0.0, 0, 0, 0])
    error = np.array([2e-5, -3e-5, 4e-5, 1e-5, -2e-5, 1e-5, 0, 0, 0])
    used = DualStageCoupling(robot_piezo)
    first = used.step(home, home - error).offsets
    at_moved = used.step(moved, moved - error).offsets
    fresh = DualStageCoupling(robot_piezo)
    assert at_moved == fresh.step(moved, moved - error).offsets
    assert at_moved != first                                  # the map changed with the pose
    used.reset()
    assert used.step(home, home - error).offsets == first     # no Jacobian kept across a reset


@pytest.mark.parametrize('reading', ['tracker', 'encoders'])
def test_midranging_moves_a_lasting_deviation_over_to_the_robot_keeping_the_tool_s_axis(robot_piezo, kin, reading):
    """A deviation that lasts and a robot that reaches its offset reference by the next step:
    the stage's offset (in Cartesian terms) is D (1 - h/T)^k after k steps, by hand from
    Delta_k = Delta_{k-1} + (h/T) u_k and u_k = D - Delta_{k-1}; the tool tip stays on the
    reference and the robot's move keeps the tool's axis. With the tracker D is a deflection d
    along the workpiece's z, D = (0, 0, -d); read from the encoders it is a robot lagging its
    reference by the same joint error e every step, D = J_P,robot e (to first order)."""
    config = robot_piezo if reading == 'tracker' else dataclasses.replace(
        robot_piezo, cartesian_dual_stage=dataclasses.replace(robot_piezo.cartesian_dual_stage, tracker=None))
    coupling = DualStageCoupling(config)
    assert coupling.offset_axes == ('px', 'py', 'pz', 'j1', 'j2', 'j3', 'j4', 'j5', 'j6')
    ref = np.array(robot_piezo.home)
    tip = kin.forward(ref)[0]
    d, rate = 100e-6, robot_piezo.control_period / robot_piezo.cartesian_dual_stage.midranging.time_constant
    assert rate == 1e-3
    lag = np.array([2e-5, -3e-5, 4e-5, 1e-5, -2e-5, 1e-5, 0, 0, 0]) * (reading == 'encoders')   # rad
    deflection = np.array([0.0, 0.0, d if reading == 'tracker' else 0.0])
    deviation = -deflection + kin.jacobian(ref)[:3] @ lag
    assert np.linalg.norm(deviation) > 20e-6
    lagging_axis = kin.forward(ref - lag)[1]
    robot = ref - lag                           # the robot's joints, the stage at home (what the tracker reads)
    for k in range(2001):
        offsets = np.array(coupling.step(ref, robot, tuple(kin.forward(robot)[0] + deflection)).offsets)
        stage = kin.jacobian(ref)[:3, 6:] @ offsets[:3]
        np.testing.assert_allclose(stage, deviation * (1 - rate) ** k, rtol=0, atol=2e-3 * d)
        robot = ref - lag
        robot[:6] += offsets[3:]
        tool = robot.copy()
        tool[6:] += offsets[:3]
        moved_tip, moved_axis = kin.forward(tool)
        assert np.linalg.norm(moved_tip + deflection - tip) < 2e-3 * d
        assert np.abs(moved_axis - lagging_axis).max() < 1e-6      # the robot's move alone: ~1e-4 rad
    assert np.linalg.norm(stage) < 0.14 * np.linalg.norm(deviation)    # (1 - 1e-3)^2000 = 0.135
    coupling.enabled = False                                            # off: no offsets, the take-over forgotten
    assert coupling.step(ref, robot, tuple(tip)).offsets == (0.0,) * 9
    coupling.enabled = True
    assert np.abs(coupling.step(ref, ref, tuple(tip + [0.0, 0.0, d])).offsets[3:]).max() < 1e-6


@pytest.fixture(scope='module')
def line_runs(robot_piezo):
    """test_robot_piezo_graph's cut, offline: from home 3 mm into the block along the face at
    10 mm/s, the coupling with and without its mid-ranging."""
    line = toolpath.from_arrays(np.linspace([0.0, 0.0, 0.0], [-3e-3, 0.0, 0.0], 31), np.tile([0.0, 0.0, 1.0], (31, 1)))
    plain = dataclasses.replace(robot_piezo, cartesian_dual_stage=dataclasses.replace(
        robot_piezo.cartesian_dual_stage, midranging=None))
    return {midranged: run_goal(config, line, feed=0.010) for midranged, config in ((False, plain), (True, robot_piezo))}


def test_midranging_in_a_cut_leaves_the_stage_the_deviations_high_pass_and_the_tool_on_the_path(robot_piezo,
                                                                                               line_runs, kin):
    """Without mid-ranging the stage's offset u is the robot's deviation D (the deflection
    most of it). With it the stage should keep T s/(T s + 1) of D, by hand from the run without:
    u_k = D_k - Delta_{k-1}, Delta_k = Delta_{k-1} + (h/T) u_k. The robot does not reach its
    offset reference at once but lags it by about 2 zeta/omega = 11 ms (its closed loop, 20 Hz),
    0.11 of T: the offsets may differ from that by 0.15 of D's largest. At the path's end the
    stage is nearer its middle by more than half, and the true tool tip stays within half the
    deflection of the path (as in test_robot_piezo_graph)."""
    fine = [robot_piezo.axis_names.index(a) for a in robot_piezo.fine_axes]
    stage = {}
    for midranged, run in line_runs.items():
        record = run.record
        assert run.goal_state == 'succeeded' and record.fault is None and record.saturations == 0, midranged
        stage[midranged] = np.array([kin.jacobian(record.reference[k])[:3, fine] @ record.offsets[k, :3]
                                     for k in range(len(record.true))])
    deviation = stage[False]
    rate = robot_piezo.control_period / robot_piezo.cartesian_dual_stage.midranging.time_constant
    expected, taken = np.zeros_like(deviation), np.zeros(3)
    for k, D in enumerate(deviation):
        expected[k] = D - taken
        taken = taken + rate * expected[k]
    largest = np.abs(deviation).max()
    assert largest > 80e-6                                                   # the deflection, ~90 um
    assert np.abs(stage[True] - expected).max() < 0.15 * largest
    end = line_runs[True].motion_end
    assert abs(stage[True][end, 2]) < 0.5 * abs(deviation[end, 2])
    run = line_runs[True]
    deflection = deflections(robot_piezo, true_geometry(robot_piezo), run.record.true)
    error = [np.linalg.norm(kin.forward(run.record.reference[k])[0] - kin.forward(run.record.true[k])[0]
                            - [0.0, 0.0, deflection[k]]) for k in range(run.motion_start, len(run.record.true), 10)]
    assert max(error) < 0.5 * np.abs(deflection).max()


def test_the_yaml_axes_are_the_experiments_axes(robot_piezo):
    """The machine's piezo axes (robot_piezo.yaml) are the ones the milling experiment
    identifies (piezo_milling.AXES): one model, written twice, kept equal here."""
    from hw_sim.piezo_stage import PiezoAxisModel
    from machine_ctrl.experiments import piezo_milling
    assert sorted(name[-1] for name in robot_piezo.fine_axes) == sorted(piezo_milling.AXES)    # px <-> x, ...
    for name in robot_piezo.fine_axes:
        experiment_axis = piezo_milling.AXES[name[-1]]
        ours = PiezoAxisModel.from_axis(robot_piezo.axis(name))
        assert np.allclose(np.ravel(ours.modes), np.ravel(experiment_axis.modes), rtol=1e-12, atol=0), name
        assert ours.real_pole == pytest.approx(experiment_axis.real_pole, rel=1e-12) if ours.real_pole else \
            experiment_axis.real_pole is None
        assert (ours.stroke, ours.sensor_noise) == (experiment_axis.stroke, experiment_axis.sensor_noise)


def test_a_law_for_another_kind_of_drive_is_refused_with_the_reason(robot_piezo, micromill):
    period = robot_piezo.control_period
    with pytest.raises(ValueError, match='axis j1: sliding_mode needs the drive.s mass and damping '
                                         r'\(a position_servo drive has none\)'):
        type(make_law(micromill.axis('x_c'), period)).from_axis(micromill.axis('x_c').control.sliding_mode,
                                                                 robot_piezo.axis('j1'), period)
    with pytest.raises(ValueError, match='axis x_c: position_command sends a position reference; a linear_motor'):
        type(make_law(robot_piezo.axis('j1'), period)).from_axis(robot_piezo.axis('j1').control.position_command,
                                                                  micromill.axis('x_c'), period)


BASE = (MACHINES / 'robot_piezo.yaml').read_text()  # edits below anchor on data, never on a comment's words


@pytest.mark.parametrize('edit, reason', [
    (('  fine: [px, py, pz]', '  fine: [px, py, qq]'), "cartesian_dual_stage.fine: unknown axis 'qq'"),
    (('  fine: [px, py, pz]', '  fine: [px, py, j6]'),
     'cartesian_dual_stage: an axis cannot be both coarse and fine'),
    (('  coarse: [j1, j2, j3, j4, j5, j6]', '  coarse: [j1, j2, j3, j4, j5]\n  extra: 1'),
     'cartesian_dual_stage: unknown key(s): extra'),
    (('      type: position_servo\n      command_limit: 3.1416',
      '      type: position_servo\n      mass: 1.0\n      command_limit: 3.1416'),
     'j1.drive: a position_servo drive has no mass or damping of its own'),
    (('      servo: {omega: 125.66370614359172, zeta: 0.7}', '      sensor_noise: 0.0'),
     'j1.plant: a position_servo drive needs servo'),
    (('        - {omega: 251.32741228718345, zeta: 0.03}\n        - {omega: 364.424747816416, zeta: 0.05}\n',
      '        []\n'), 'px.plant: a piezo drive needs modes'),
    (('        - {omega: 251.32741228718345, zeta: 0.03}', '        - {omega: 251.32741228718345, zeta: 1.2}'),
     'px.plant: modes: zeta must be below 1'),
    (('      sensor_noise: 2.0e-8', '      servo: {omega: 10.0, zeta: 0.5}\n      sensor_noise: 2.0e-8'),
     'px.plant: servo: only for position_servo'),
    (('      command_limit: 3.1416', '      force_constant: 2.0\n      command_limit: 3.1416'),
     'j1.drive: a position_servo drive has no force_constant'),
    (('  coarse: [j1, j2, j3, j4, j5, j6]\n  fine: [px, py, pz]', '  coarse: [j1, j2, j3, j4, j5]\n  fine: [px, py, pz, j6]'),
     'cartesian_dual_stage.fine: 4 fine axes'),
    (('  coarse: [j1, j2, j3, j4, j5, j6]\n  fine: [px, py, pz]', '  coarse: [j1, j2, j3, j4, j5]\n  fine: [px, py, j6]'),
     'cartesian_dual_stage.fine: fine axes must be linear with a stroke'),
    (('    time_constant: 0.1 ', '    time_constant: 0.0 '), 'cartesian_dual_stage.midranging.time_constant: must be > 0'),
    (('    time_constant: 0.1 ', '    time_constant: .nan '), 'cartesian_dual_stage.midranging.time_constant'),
    (('    time_constant: 0.1 ', '    gain: 1.0 '), 'cartesian_dual_stage.midranging.time_constant: missing'),
    (('    time_constant: 0.1 ', '    time_constant: 1.0e-4 '),
     'cartesian_dual_stage.midranging.time_constant: 0.0001 s must be above the control period 0.0001 s'),
])
def test_a_bad_robot_piezo_config_is_refused_with_the_reason(tmp_path, edit, reason):
    old, new = edit
    assert old in BASE
    (tmp_path / 'robot_piezo.urdf').write_text((MACHINES / 'robot_piezo.urdf').read_text())
    path = tmp_path / 'm.yaml'
    path.write_text(BASE.replace(old, new, 1))
    with pytest.raises(ConfigError) as info:
        load_machine(path)
    assert reason in str(info.value)


def test_modes_on_a_drive_that_is_not_piezo_are_refused(tmp_path):
    import yaml
    data = yaml.safe_load((MACHINES / 'trt_5axis.yaml').read_text())
    data['axes']['x']['plant']['modes'] = [{'omega': 10.0, 'zeta': 0.1}]
    (tmp_path / 'trt_5axis.urdf').write_text((MACHINES / 'trt_5axis.urdf').read_text())
    path = tmp_path / 'm.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r'axes\.x\.plant: modes: only for piezo drives'):
        load_machine(path)


@pytest.fixture(scope='module')
def face_runs(robot_piezo):
    """A 1 mm circle on the workpiece's face at the feed of Sörnmo section 2.7 (7.5 mm/s),
    from home, offline with the coupling off and on."""
    cl = toolpath.circle_xy(radius=0.5e-3, points=91)
    return {on: run_goal(robot_piezo, cl, feed=7.5e-3, dual_stage=on) for on in (False, True)}


def test_milling_with_the_piezo_compensation_follows_the_path_closer(robot_piezo, face_runs, kin):
    """The true tool tip (the arm's deflection under the cut included) against the reference's."""
    errors = {}
    for on, run in face_runs.items():
        record = run.record
        assert run.goal_state == 'succeeded' and record.fault is None, (on, record.fault)
        deflection = deflections(robot_piezo, true_geometry(robot_piezo), record.true)
        rows = range(run.motion_start, min(run.motion_end, len(record.true)), 10)
        errors[on] = np.array([np.linalg.norm(kin.forward(record.reference[k])[0] - kin.forward(record.true[k])[0]
                                              - [0.0, 0.0, deflection[k]]) for k in rows])
        moved = np.abs(record.true[:, 6:]).max()
        assert (moved > 1e-6) == on                       # the stage moves only with the coupling
    rms = {on: float(np.sqrt(np.mean(e ** 2))) for on, e in errors.items()}
    assert errors[True].mean() < 0.8 * errors[False].mean() and rms[True] < rms[False], rms
