"""The fourth machine, robot_piezo (issue [4/8]; Sörnmo seed 004): an ABB IRB 2400 holding the
workpiece and the 3-axis piezo micro manipulator carrying the tool. Checked without ROS:
its kinematics against the manufacturer's numbers, the two new drives (a joint closing its
own position loop, a piezo stage of modes) against their transfer functions, the two new
laws, the Cartesian coupling against the kinematics it cancels, bad configs refused with the
reason, and an offline milling run with the coupling on and off."""
import math
import random
from pathlib import Path

import numpy as np
import pytest

from hw_sim.offline_goal import run_goal
from hw_sim.simulator import make_plant
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
    with pytest.raises(ValueError, match='axis j1: the lqg law needs a piezo drive with plant.modes'):
        LqgLaw.from_axis(robot_piezo.axis('px').control.lqg, robot_piezo.axis('j1'), period)


def test_the_cartesian_coupling_cancels_the_tool_deviation_of_the_robots_errors(robot_piezo, kin):
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


BASE = (MACHINES / 'robot_piezo.yaml').read_text()


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
    text = (MACHINES / 'trt_5axis.yaml').read_text().replace(
        "    plant: {}                  # Table 1 rigid body; linear drives frictionless (Table 1 identifies viscous "
        "damping only)", '    plant: {modes: [{omega: 10.0, zeta: 0.1}]}', 1)
    (tmp_path / 'trt_5axis.urdf').write_text((MACHINES / 'trt_5axis.urdf').read_text())
    path = tmp_path / 'm.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError, match=r'axes\.x\.plant: modes: only for piezo drives'):
        load_machine(path)


@pytest.fixture(scope='module')
def face_runs(robot_piezo):
    """A 1 mm circle on the workpiece's face at the feed of Sörnmo section 2.7 (7.5 mm/s),
    from home, offline with the coupling off and on."""
    cl = toolpath.circle_xy(radius=0.5e-3, points=91)
    return {on: run_goal(robot_piezo, cl, feed=7.5e-3, dual_stage=on) for on in (False, True)}


def test_milling_with_the_piezo_compensation_follows_the_path_closer(face_runs, kin):
    errors = {}
    for on, run in face_runs.items():
        record = run.record
        assert run.goal_state == 'succeeded' and record.fault is None, (on, record.fault)
        rows = range(run.motion_start, min(run.motion_end, len(record.true)), 10)
        errors[on] = np.array([np.linalg.norm(kin.forward(record.reference[k])[0] - kin.forward(record.true[k])[0])
                               for k in rows])
        moved = np.abs(record.true[:, 6:]).max()
        assert (moved > 1e-6) == on                       # the stage moves only with the coupling
    rms = {on: float(np.sqrt(np.mean(e ** 2))) for on, e in errors.items()}
    assert errors[True].mean() < 0.8 * errors[False].mean() and rms[True] < rms[False], rms
