"""Machine descriptions load into typed dataclasses; every bad value stops loading with one
line naming the file, the key and the problem."""
import subprocess
import sys
from pathlib import Path

import pytest

from machine_ctrl.model.config import available_machines, load_machine
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.model.kinematics import Kinematics

MACHINES = Path(__file__).resolve().parents[1] / 'config' / 'machines'


def test_shipped_machines_load(micromill, trt):
    assert {'micromill_9axis', 'trt_5axis'} <= set(available_machines())
    assert micromill.axis_names == ('x_c', 'y_c', 'z_c', 'x_f', 'y_f', 'z_f', 'a_f', 'b_f', 'c_f')
    assert trt.axis_names == ('x', 'y', 'z', 'a', 'c')
    assert micromill.control_period == 1e-4 and trt.control_period == 1e-3
    x_c = micromill.axis('x_c')
    assert x_c.stroke == (-0.05, 0.05) and x_c.kind == 'linear'
    assert x_c.drive.gain == pytest.approx(45.4)          # K_a K_t, thesis Table 4.3
    assert micromill.axis('c_f').stroke is None            # unlimited
    assert micromill.axis('a_f').stroke == pytest.approx((-0.5 * 3.141592653589793 / 180,
                                                           0.5 * 3.141592653589793 / 180))
    assert micromill.axis('x_f').stroke == (-100e-6, 100e-6)


def edited_machine(tmp_path, yaml_edit=None, urdf_edit=None, name='micromill_9axis'):
    """A copy of machine `name` in tmp_path with one (old, new) edit of its YAML and of its URDF.
    The edits anchor on data, never on a comment's words (a comment reworded must not fail a test)."""
    for suffix, edit in (('yaml', yaml_edit), ('urdf', urdf_edit)):
        text = (MACHINES / f'{name}.{suffix}').read_text()
        if edit:
            old, new = edit
            assert old in text, f'test edit does not apply: {old!r}'
            text = text.replace(old, new, 1)
        (tmp_path / f'{name}.{suffix}').write_text(text)
    return tmp_path / f'{name}.yaml'


X_C_LIMIT = '<limit lower="-0.050" upper="0.050" velocity="0.15" effort="364"/>'

BAD_CONFIGS = {
    'missing stroke': (None, (X_C_LIMIT, '<limit velocity="0.15" effort="364"/>'),
                       r'micromill_9axis\.urdf: joint x_c: <limit lower=\.\.\.> stroke missing'),
    'inverted stroke': (None, (X_C_LIMIT, X_C_LIMIT.replace('-0.050', '0.07')),
                        r'joint x_c: stroke lower 0\.07 is not below upper 0\.05'),
    'negative mass': (('mass: 21.19', 'mass: -21.19'), None,
                      r'micromill_9axis\.yaml: axes\.x_c\.drive\.mass: must be > 0, got -21\.19'),
    'negative true mass': (('      mass: 21.44 ', '      mass: -21.44 '), None,
                           r'micromill_9axis\.yaml: axes\.x_c\.plant\.mass: must be > 0, got -21\.44'),
    'no true mass': (('      mass: 21.44', '      # mass: 21.44'), None,
                     r"axes\.x_c\.plant: a linear_motor drive's plant needs mass and damping: the truth hw_sim simulates"),
    'unknown axis': (('  x_c:\n', '  x_cc:\n'), None,
                     r'micromill_9axis\.yaml: axes\.x_cc: unknown axis'),
    'malformed urdf': (None, ('</robot>', ''), r'micromill_9axis\.urdf: malformed URDF'),
    'dangling link': (None, ('<child link="rotor"/>', '<child link="rotr"/>'),
                      r"malformed URDF: joint rotor_mount: child link 'rotr' is not a <link>"),
    'missing key': (('      jerk: 100.0', '      # jerk: 100.0'), None,
                    r'axes\.x_c\.limits\.jerk: missing'),
    'unknown key': (('    sensor_resolution: 40.0e-9', '    resolution: 1\n    sensor_resolution: 40.0e-9'),
                    None, r'axes\.x_c: unknown key\(s\): resolution'),
    'not a number': (('control_period: 1.0e-4', 'control_period: fast'), None,
                     r"control_period: must be a number, got 'fast'"),
    'velocity mismatch': (('velocity: 0.15', 'velocity: 0.2'), None,
                          r'axes\.x_c\.limits\.velocity: 0\.2 differs from the URDF joint velocity limit 0\.15'),
    'unknown drive': (('type: linear_motor', 'type: hydraulic'), None,
                      r'axes\.x_c\.drive\.type: must be one of .*got .hydraulic.'),
    'axis missing': (('  c_f:\n', '  c_f_removed:\n'), None, r'axes\.c_f_removed: unknown axis'),
    'bad yaml': (('name: micromill_9axis', 'name: [unclosed'), None, r'cannot read'),
    'contour control: unknown axis': (('axes: [x_f, y_f, z_f]', 'axes: [x_f, y_g]'), None,
                                      r"contour_control\.axes: unknown axis 'y_g'"),
    'contour control: no linear axis': (('axes: [x_f, y_f, z_f]', 'axes: [a_f, b_f]'), None,
                                        r'contour_control\.axes: the tool-tip channel needs at least one linear axis'),
    'contour control: orientation without rotary axis': (
        ('  fade: 0.01', '  orientation: {proportional: 1.0, integral: 10.0}\n  fade: 0.01'), None,
        r'contour_control\.orientation: the orientation channel needs a rotary axis among axes'),
    'contour control: rotary axis without orientation channel': (
        ('axes: [x_f, y_f, z_f]', 'axes: [x_f, y_f, z_f, a_f]'), None,
        r'contour_control\.axes: a_f: a rotary axis takes the orientation correction, and there is no orientation'),
    'contour control: negative gain': (('    proportional: 1.0', '    proportional: -1.0'), None,
                                       r'contour_control\.tool_tip\.proportional: must be >= 0, got -1'),
    'contour control: zero fade': (('  fade: 0.01', '  fade: 0.0'), None,
                                   r'contour_control\.fade: must be > 0, got 0'),
    'contour control: unknown estimator': (('estimator: compensated', 'estimator: exact'), None,
                                           r'contour_control\.estimator: must be one of'),
}


def test_the_plant_is_the_truth_and_the_drive_the_belief(micromill):
    """x_c's plant carries a workpiece the controllers' Table 4.1 mass does not know; z_c's
    plant has no mass of its own and simulates the drive's."""
    x_c, z_c = micromill.axis('x_c'), micromill.axis('z_c')
    assert (x_c.drive.mass, x_c.plant.mass) == (21.19, 21.44)
    assert x_c.plant.damping == x_c.drive.damping == 25.05
    assert z_c.plant.mass == z_c.drive.mass == 17.61 and z_c.plant.damping == z_c.drive.damping == 102.9


def test_a_true_mass_on_a_drive_without_a_rigid_body_is_refused(tmp_path):
    """robot_piezo's piezo stage is its closed loop (modes): a plant mass there means nothing."""
    px_plant = '    plant:\n      modes:'
    path = edited_machine(tmp_path, (px_plant, px_plant.replace('plant:\n', 'plant:\n      mass: 1.0\n')),
                          name='robot_piezo')
    with pytest.raises(ConfigError, match=r'axes\.px\.plant: mass: a true body apart from the drive\'s is only '
                                          r'for linear_motor, maglev, servo_voltage, voice_coil drives'):
        load_machine(path)


def test_a_belief_file_changes_the_controllers_values_and_not_the_plant(micromill, tmp_path):
    belief = tmp_path / 'belief.yaml'
    belief.write_text('axes:\n  x_c:\n    drive: {mass: 22.0, damping: 30.0}\n'
                      '    control:\n      lugre_feedforward: {coulomb: 33.0}\n')
    machine = load_machine('micromill_9axis', belief=[belief])
    x_c, before = machine.axis('x_c'), micromill.axis('x_c')
    assert (x_c.drive.mass, x_c.drive.damping, x_c.control.lugre_feedforward.coulomb) == (22.0, 30.0, 33.0)
    assert x_c.control.lugre_feedforward.static == before.control.lugre_feedforward.static      # merged, not replaced
    assert x_c.plant == before.plant and machine.axis('y_c') == micromill.axis('y_c')


@pytest.mark.parametrize('text, message', [
    ('axes:\n  x_c:\n    plant: {mass: 30.0}\n',
     r'belief\.yaml: axes\.x_c\.plant: a belief file sets only drive\.mass, drive\.damping, drive\.flexure, '
     r'drive\.modes, drive\.real_pole, control \(the plant is the truth hw_sim simulates\)'),
    ('axes:\n  x_c:\n    drive: {force_constant: 50.0}\n',
     r"axes\.x_c\.drive: force_constant: a belief file sets only a linear_motor drive's mass and damping"),
    ('axes:\n  x_c:\n    drive: {modes: [{omega: 100.0, zeta: 0.1}]}\n',
     r"axes\.x_c\.drive: modes: a belief file sets only a linear_motor drive's mass and damping"),
    ('axes:\n  x_c:\n    drive: {flexure: {stiffness: 1.0, secondary_mass: 1.0, secondary_stiffness: 1.0}}\n',
     r"axes\.x_c\.drive: flexure: a belief file sets only a linear_motor drive's mass and damping"),
    ('axes:\n  q:\n    drive: {mass: 1.0}\n', r'belief\.yaml: axes\.q: unknown axis'),
    ('control_period: 1.0e-3\naxes: {}\n', r'belief\.yaml: <top>: unknown key\(s\): control_period'),
    ('axes:\n  x_c:\n    drive: {mass: -1.0}\n',
     r'^\S*belief\.yaml \(over micromill_9axis\.yaml\): axes\.x_c\.drive\.mass: must be > 0, got -1'),
    ('axes:\n  x_c:\n    control: {law: ppi}\n',
     r"belief\.yaml: axes\.x_c\.control: law: a belief file sets only the numbers of the axis's lugre_feedforward "
     r'and sliding_mode'),
    ('axes:\n  x_c:\n    control:\n      ppi: {position_gain: 1.0}\n',
     r"belief\.yaml: axes\.x_c\.control: ppi: a belief file sets only the numbers"),
    ('axes:\n  x_f:\n    control:\n      lugre_feedforward: {coulomb: 1.0}\n',
     r"belief\.yaml: axes\.x_f\.control: lugre_feedforward: a belief file sets only the numbers of the axis's lead_lag"),
    ('axes:\n  x_c:\n    drive: null\n', r'belief\.yaml: axes\.x_c\.drive: must be a mapping'),
])
def test_a_belief_file_beyond_the_controllers_values_is_refused(tmp_path, text, message):
    belief = tmp_path / 'belief.yaml'
    belief.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_machine('micromill_9axis', belief=[belief])


def test_a_belief_file_changes_only_the_axis_it_names_where_the_yaml_shares_a_section(tmp_path):
    """robot_piezo's joints share j1's control section (a YAML anchor); its piezo drives are
    their own plant, so a belief does not set their mass."""
    machine = load_machine('robot_piezo')
    lead = machine.axis('j1').control.position_command.velocity_lead
    belief = tmp_path / 'belief.yaml'
    belief.write_text(f'axes:\n  j1:\n    control:\n      position_command: {{velocity_lead: {2 * lead}}}\n')
    changed = load_machine('robot_piezo', belief=[belief])
    assert changed.axis('j1').control.position_command.velocity_lead == 2 * lead
    assert changed.axis('j2').control == machine.axis('j2').control
    belief.write_text('axes:\n  px:\n    drive: {mass: 1.0}\n')
    with pytest.raises(ConfigError, match=r"axes\.px\.drive: mass: a belief file sets only a piezo drive's modes and "
                                          r'real_pole'):
        load_machine('robot_piezo', belief=[belief])
    belief.write_text('axes:\n  j2:\n    drive: {mass: 1.0}\n')
    with pytest.raises(ConfigError, match=r'axes\.j2\.drive: a position_servo drive has no model of its own apart '
                                          r'from its simulated plant'):
        load_machine('robot_piezo', belief=[belief])


def test_a_piezo_drives_model_is_the_controllers_and_a_belief_file_replaces_it(tmp_path):
    """robot_piezo: drive.modes (identified) is what the LQG designs from, plant.modes the
    truth; a belief file's modes replace the drive's of its axis only, the plant untouched;
    a piezo drive without a model, or a model on another drive, is refused."""
    machine = load_machine('robot_piezo')
    px = machine.axis('px')
    assert px.drive.modes != px.plant.modes and len(px.drive.modes) == len(px.plant.modes) == 2
    belief = tmp_path / 'belief.yaml'
    belief.write_text('axes:\n  px:\n    drive:\n      modes: [{omega: 250.0, zeta: 0.02}]\n      real_pole: 90.0\n')
    changed = load_machine('robot_piezo', belief=[belief])
    assert [(m.omega, m.zeta) for m in changed.axis('px').drive.modes] == [(250.0, 0.02)]
    assert changed.axis('px').drive.real_pole == 90.0 and changed.axis('px').plant == px.plant
    assert changed.axis('py') == machine.axis('py')            # the drives share a YAML anchor
    for old, new, message in (
            ('      modes: [{omega: 251.403, zeta: 0.02958}, {omega: 362.949, zeta: 0.04772}]', '',
             r'axes\.px\.drive: .*a piezo drive needs modes \(at least one: omega, zeta\): the controllers\' model'),
            ('      type: position_servo\n', '      type: position_servo\n      real_pole: 3.0\n',
             r"axes\.j1\.drive: modes and real_pole: only for piezo drives"),
            ('      modes: [{omega: 295.325, zeta: 0.04056}]', '',
             r'axes\.py\.drive: .*a piezo drive needs modes'),          # py does not inherit px's model
            ('      modes: [{omega: 295.325, zeta: 0.04056}]', '      modes: [{omega: 295.325, zeta: 1.5}]',
             r'axes\.py\.drive: modes: zeta must be below 1')):
        with pytest.raises(ConfigError, match=message):
            load_machine(edited_machine(tmp_path, (old, new), name='robot_piezo'))


def test_a_flexure_stages_model_is_the_controllers_and_a_belief_file_replaces_it(tmp_path):
    """fts_lathe's W: the drive's mass, damping and flexure are what the H2 law designs from,
    the plant's the truth; a belief file sets the drive's alone; the plant's truth is required,
    and a flexure model on another drive is refused."""
    machine = load_machine('fts_lathe')
    w = machine.axis('w')
    belief = tmp_path / 'belief.yaml'
    belief.write_text('axes:\n  w:\n    drive:\n      mass: 0.08\n      flexure: {stiffness: 30000.0, secondary_mass: '
                      '0.01, secondary_stiffness: 60000.0, secondary_damping: 5.0}\n')
    changed = load_machine('fts_lathe', belief=[belief]).axis('w')
    assert (changed.drive.mass, changed.drive.damping) == (0.08, w.drive.damping)
    assert (changed.drive.flexure.stiffness, changed.drive.flexure.secondary_damping) == (30000.0, 5.0)
    assert changed.plant == w.plant
    for old, new, message in (
            ('      mass: 0.074', '      # mass: 0.074',
             r"axes\.w\.plant: a voice_coil drive's plant needs mass and damping: the truth hw_sim simulates"),
            ('      type: servo_voltage\n', '      type: servo_voltage\n      flexure: {stiffness: 1.0, '
             'secondary_mass: 1.0, secondary_stiffness: 1.0, secondary_damping: 1.0}\n',
             r'axes\.c\.drive: flexure: only for voice_coil drives')):
        with pytest.raises(ConfigError, match=message):
            load_machine(edited_machine(tmp_path, (old, new), name='fts_lathe'))


@pytest.mark.parametrize('case', sorted(BAD_CONFIGS))
def test_bad_config_is_rejected_with_one_line(tmp_path, case):
    yaml_edit, urdf_edit, message = BAD_CONFIGS[case]
    path = edited_machine(tmp_path, yaml_edit, urdf_edit)
    with pytest.raises(ConfigError, match=message) as info:
        load_machine(path)
    assert '\n' not in str(info.value)


def test_urdf_joint_without_axis_entry_is_rejected(tmp_path):
    text = (MACHINES / 'micromill_9axis.yaml').read_text()
    start = text.index('  c_f:\n')
    path = edited_machine(tmp_path, (text[start:], ''))
    with pytest.raises(ConfigError, match=r'axes: URDF joint\(s\) without an axis entry: c_f'):
        load_machine(path)


def test_unknown_machine_lists_the_available_ones():
    with pytest.raises(ConfigError, match=r'nosuch: unknown machine \(available: .*micromill_9axis'):
        load_machine('nosuch')


def test_pinocchio_failure_is_one_line(tmp_path, micromill):
    bad = tmp_path / 'bad.urdf'
    bad.write_text('<robot name="r"><link name="a"/><joint name="j" type="prismatic"></joint></robot>')
    with pytest.raises(ConfigError) as info:
        Kinematics(bad, micromill.axis_names, 'a', 'a')
    assert str(bad) in str(info.value) and '\n' not in str(info.value)


def test_cli_reports_config_error_in_one_line_and_exit_2(tmp_path):
    path = edited_machine(tmp_path, ('mass: 21.19', 'mass: -21.19'))
    result = subprocess.run([sys.executable, '-m', 'machine_ctrl.app.cli', 'info', str(path)],
                            capture_output=True, text=True)
    assert result.returncode == 2
    assert result.stdout == ''
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and 'axes.x_c.drive.mass: must be > 0' in lines[0]
