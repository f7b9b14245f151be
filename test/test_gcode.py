"""G-code in (issue [7/8], part 1; trajectory/gcode.py, trajectory/part_program.py): programs of
known geometry — arc end points, centres and radii in each plane, helix pitch, inch against
mm, incremental against absolute, inverse time — checked against geometry written here (the
rotation about the plane's normal, the chord construction of an R arc), malformed programs
each refused with its line and reason, the cut into pieces, and a program planned through
the machine's kinematics: the tool tip of the planned references (forward kinematics) on
the programmed circle and at every block's end."""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics
from trajectory import gcode
from trajectory.gcode import GcodeStatus, parse, pieces
from trajectory.part_program import plan_program
from trajectory.planner import PlanStatus

MM = 1e-3


def motions(text: str):
    result = parse(text)
    assert result.ok, result.reason
    return result.program.motions


def rotation(axis: str, angle: float) -> np.ndarray:
    """Right-handed rotation about +X, +Y or +Z."""
    c, s = math.cos(angle), math.sin(angle)
    return {'x': np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            'y': np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            'z': np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


@pytest.mark.parametrize('plane, normal, start, end, centre_words', [
    ('G17', 'z', (5, 0, 0), (0, 5, 0), 'I-5 J0'),
    ('G18', 'y', (5, 0, 0), (0, 0, -5), 'I-5 K0'),     # counter-clockwise about +Y takes +X to -Z
    ('G19', 'x', (0, 5, 0), (0, 0, 5), 'J-5 K0'),
])
def test_a_counter_clockwise_quarter_in_each_plane_turns_about_its_positive_normal(plane, normal, start, end,
                                                                                   centre_words):
    x, y, z = end
    (_, arc) = motions(f'{plane} G0 X{start[0]} Y{start[1]} Z{start[2]}\n'
                       f'G3 X{x} Y{y} Z{z} {centre_words} F60')
    assert arc.arc.sweep == pytest.approx(math.pi / 2, abs=1e-12)
    u = np.linspace(0, 1, 9)
    expected = np.array([rotation(normal, t * math.pi / 2) @ np.array(start, float) * MM for t in u])
    assert np.abs(arc.point(u) - expected).max() < 1e-15
    assert arc.length == pytest.approx(math.pi / 2 * 5 * MM, rel=1e-12)


def test_clockwise_is_the_other_way_round_and_a_full_circle_needs_only_its_centre():
    (_, quarter) = motions('G0 X5\nG2 X0 Y-5 I-5 F60')
    assert quarter.arc.sweep == pytest.approx(-math.pi / 2, abs=1e-12)
    mid = quarter.point(np.array([0.5]))[0]
    assert np.allclose(mid, rotation('z', -math.pi / 4) @ np.array([5 * MM, 0, 0]), atol=1e-15)
    (_, circle) = motions('G0 X5\nG2 X5 Y0 I-5 F60')
    assert circle.arc.sweep == pytest.approx(-2 * math.pi, abs=1e-12)
    points = circle.point(circle.samples())
    assert np.abs(np.linalg.norm(points, axis=1) - 5 * MM).max() < 1e-15
    assert circle.length == pytest.approx(2 * math.pi * 5 * MM, rel=1e-12)


def test_an_r_arc_takes_the_short_way_with_a_positive_radius_and_the_long_way_with_a_negative_one():
    # chord from (10, 0) to (0, 10), radius 10: the centres are (0, 0) and (10, 10)
    (_, short) = motions('G0 X10\nG3 X0 Y10 R10 F60')
    assert np.allclose(short.arc.centre, [0, 0, 0], atol=1e-15)
    assert short.arc.sweep == pytest.approx(math.pi / 2)
    (_, long) = motions('G0 X10\nG3 X0 Y10 R-10 F60')
    assert np.allclose(long.arc.centre, [10 * MM, 10 * MM, 0], atol=1e-15)
    assert long.arc.sweep == pytest.approx(3 * math.pi / 2)
    (_, clockwise) = motions('G0 X10\nG2 X0 Y10 R10 F60')
    assert np.allclose(clockwise.arc.centre, [10 * MM, 10 * MM, 0], atol=1e-15)
    assert clockwise.arc.sweep == pytest.approx(-math.pi / 2)


def test_a_helix_climbs_its_pitch_per_turn():
    (_, helix) = motions('G0 X5\nG3 X5 Y0 Z-3 I-5 F60')
    points = helix.point(np.linspace(0, 1, 401))
    angle = np.unwrap(np.arctan2(points[:, 1], points[:, 0]))
    assert np.allclose(points[:, 2], -3 * MM * angle / (2 * math.pi), atol=1e-15)     # linear in the angle
    assert helix.length == pytest.approx(math.hypot(2 * math.pi * 5 * MM, 3 * MM), rel=1e-12)


def test_inches_incremental_distances_and_inverse_time():
    (line,) = motions('G20 G1 X1 F10')
    assert line.end[0] == pytest.approx(25.4e-3) and line.feed == pytest.approx(10 * 25.4e-3 / 60)
    moves = motions('G91 G1 X1 F60\nX1 Y2\nG90 X0 Y0')
    assert [list(np.round(m.end / MM, 12)) for m in moves] == [[1, 0, 0], [2, 2, 0], [0, 0, 0]]
    (timed,) = motions('G93 G1 X6 F10')                 # the block takes 1/10 min: 6 mm in 6 s
    assert timed.feed == pytest.approx(1e-3)
    a, b = motions('G91 G0 A10 X1\nA5 X1')
    assert b.rotary_end == pytest.approx((math.radians(15), 0.0, 0.0))


def test_what_is_read_and_ignored_is_said():
    result = parse('%\nN10 G17 G21 G40 G49 G54 G61 G80 G90 G91.1 G94 (header)\nG0 X1 S2000 M3\n'
                   'G1 X2 F100 ; cut (at last)\nG1 (on; and on) X2\nM5 M30\nG0 X9\n%', 'p.ngc')
    assert result.ok, result.reason
    assert [m.line for m in result.program.motions] == [3, 4]
    assert result.program.notes == (
        'line 3: S2000 (spindle speed) ignored: the simulated machines have no spindle',
        'line 3: M3 (spindle) ignored: the simulated machines have no spindle',
        'line 5: no motion (the block ends where it starts)',
        'line 6: M5 (spindle) ignored: the simulated machines have no spindle',
        'line 6: program end; the 1 block(s) after it are not read')


@pytest.mark.parametrize('program, line, reason', [
    ('G0 X1\nG1 X2', 2, 'a feed move without a feed rate (F)'),
    ('X1', 1, 'X without a motion mode'),
    ('G0 X1 G1', 1, 'two motion codes in one block (G0 and G1)'),
    ('G1 X1 I2 F60', 1, 'I with G1: centre words belong to an arc'),
    ('G1 F60\nG2 X1 R0.4', 2, 'is less than half the chord'),
    ('G1 F60\nG2 X1 Y0 I0.4 J0', 2, 'the arc end is not on its circle: 0.4 from the centre at the start, 0.6 at the end'),
    ('G1 F60\nG3 X0 Y0 R5', 2, 'a full circle needs I J K'),
    ('G18 G2 X1 J1 F60', 1, 'J is not in the arc plane G18 (its centre words are K I)'),
    ('G1 F60\nG2 X1 R1 I1', 2, 'R and I J K in one arc'),
    ('G1 X1 F0', 1, 'F0: a feed rate must be positive'),
    ('G93 G1 X1 F10\nX2', 2, 'inverse time (G93): every feed block needs its own F'),
    ('G21 G1 X1 F60\nG20\nG1 X2', 3, 'a feed move without a feed rate'),
    ('G0 X1 X2', 1, 'X appears twice in the block'),
    ('G0 X#1', 1, "cannot read 'X#1'"),
    ('G0 X[1+2]', 1, "cannot read"),
    ('G43 H1', 1, 'G43 is not supported'),
    ('G0 X1\nM8', 2, 'M8 is not supported'),
    ('T1 M6', 1, 'the word T is not supported'),
    ('G0 X1 (open', 1, 'an unclosed or nested comment'),
    ('/G0 X1', 1, 'block delete'),
    ('M0', 1, 'M0 before any motion'),
    ('G0 A10', 1, 'a rotary move with the tool tip standing still'),
    ('G0 X1\nM' + '9' * 400, 2, 'the number is too large'),
    ('G1 F100\nG2 X1 I1000000000000', 2, 'I1e+12: farther than 2 m from the origin'),
    ('G1 X100000 F100', 1, 'the end point [100000.0, 0.0, 0.0]: farther than 2 m from the origin'),
    ('G91 G0 X1500\nX1500', 2, 'the end point [3000.0, 0.0, 0.0]: farther than 2 m'),
    ('G20 G21 G0 X1', 1, 'G20 and G21 in one block (both set the units)'),
    ('G0 X1 G90 G91', 1, 'G90 and G91 in one block (both set the distance)'),
])
def test_a_malformed_program_is_refused_with_its_line_and_reason(program, line, reason):
    result = parse(program, 'bad.ngc')
    assert result.status == GcodeStatus.INVALID_INPUT and result.program is None
    assert result.reason.startswith(f'bad.ngc:{line}: ') and reason in result.reason, result.reason


def test_a_move_too_short_for_its_samples_is_no_motion_and_the_closing_percent_ends_the_program(tmp_path):
    program = tmp_path / 'p.ngc'
    program.write_bytes('\ufeff%\nG0 X1\nG1 X1.000003 F60\nG1 X2\n%\nG0 X9\n'.encode())    # with a byte-order mark
    result = gcode.read(program)
    assert result.ok, result.reason
    assert [m.line for m in result.program.motions] == [2, 4]
    assert result.program.notes == ('line 3: no motion (a move of 3e-09 m, shorter than 5e-09 m)',
                                    'line 5: program end; the 1 block(s) after it are not read')


def test_the_program_is_cut_at_corners_feed_changes_rapids_and_stops():
    program = parse('G0 X-5 Y0\n'
                    'G1 X10 F600\n'           # a corner at (10, 0): a new piece
                    'G1 Y5\n'
                    'G3 X5 Y10 I-5 J0\n'      # tangent to the line before it: the same piece
                    'G1 X0 F300\n'            # tangent, but another feed
                    'M0\n'
                    'G1 X-5\n').program       # straight on after the stop: a piece of its own
    cut = pieces(program)
    assert [(p.lines, p.rapid, p.stop_after) for p in cut] == [
        ((1, 1), True, False), ((2, 2), False, False), ((3, 4), False, False), ((5, 5), False, True),
        ((7, 7), False, False)]
    assert cut[0].feed == gcode.RAPID_FEED and cut[2].feed == pytest.approx(10e-3) and cut[3].feed == pytest.approx(5e-3)
    joined = cut[2].cl.positions
    assert np.allclose(joined[0], [10 * MM, 0, 0]) and np.allclose(joined[-1], [5 * MM, 10 * MM, 0])
    gaps = np.linalg.norm(np.diff(joined, axis=0), axis=1)
    assert gaps.max() <= gcode.MAX_SPACING * (1 + 1e-12)


def test_rotary_words_need_a_machine_with_that_axis(trt):
    program = parse('G0 X1\nG1 X2 B5 F60').program
    with pytest.raises(gcode.GcodeError, match='rotary words'):
        pieces(program)
    kinematics = Kinematics.from_config(trt)
    with pytest.raises(gcode.GcodeError, match='trt_5axis has no rotary axis for B'):
        pieces(program, gcode.tool_axis_of(kinematics, trt))
    tilted = pieces(parse('G0 X1\nG1 X2 A5 F60').program, gcode.tool_axis_of(kinematics, trt))[1]
    home = kinematics.forward(np.array(trt.home))[1]               # A0 B0 C0: the machine's home orientation
    angles = np.degrees(np.arccos(np.clip(tilted.cl.axes @ home, -1, 1)))
    assert angles[0] == pytest.approx(0.0, abs=1e-6) and angles[-1] == pytest.approx(5.0, abs=1e-9)
    assert np.all(np.diff(angles) > 0)                              # turning all the way


def test_rapids_are_bound_by_the_axes_alone():
    for name in ('micromill_9axis', 'trt_5axis', 'fts_lathe', 'robot_piezo'):
        machine = load_machine(name)
        assert sum(a.limits.velocity for a in machine.axes if a.kind == 'linear') < gcode.RAPID_FEED, name


CIRCLE = """% (a circle of radius 2 mm from a rapid approach)
G17 G21 G90 G94
G0 X2 Y0 Z0.5
G1 Z0 F120
G3 X2 Y0 I-2 J0 F300
G1 X1
G0 Z0.5
M30
"""


@pytest.fixture(scope='module')
def circle_plan(tmp_path_factory, trt):
    path = tmp_path_factory.mktemp('gcode') / 'circle.ngc'
    path.write_text(CIRCLE)
    return path, plan_program(path, trt)


def test_a_planned_program_puts_the_tool_on_the_programmed_circle_and_every_block_end(circle_plan, trt):
    _, result = circle_plan
    assert result.ok, result.reason
    assert [p.lines for p in result.pieces] == [(3, 3), (4, 4), (5, 5), (6, 6), (7, 7)]
    kinematics = Kinematics.from_config(trt)
    ends = [(2, 0, 0.5), (2, 0, 0), (2, 0, 0), (1, 0, 0), (1, 0, 0.5)]
    for planned, end in zip(result.plans, ends):
        tip, _ = kinematics.forward(planned.reference.position[-1])
        assert np.abs(tip - np.array(end) * MM).max() < 1e-9
    circle = result.plans[2].reference.position
    tips = np.array([kinematics.forward(q)[0] for q in circle[::10]])
    assert np.abs(np.linalg.norm(tips[:, :2], axis=1) - 2 * MM).max() < 1e-8      # on the circle
    assert np.abs(tips[:, 2]).max() < 1e-9
    reference = result.reference()
    assert len(reference) == sum(len(p.reference) for p in result.plans) - (len(result.plans) - 1)
    assert result.summary()['traversal_time'] == pytest.approx((len(reference) - 1) * reference.period, abs=1e-9)


def test_the_command_plans_a_program_and_names_the_line_of_a_bad_one(circle_plan, tmp_path):
    path, _ = circle_plan
    exe = str(Path(sys.executable).parent / 'machine-ctrl')
    done = subprocess.run([exe, 'plan', str(path), '--machine', 'trt_5axis', '--out', str(tmp_path), '--json'],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert [p['lines'] for p in summary['pieces']] == [[3, 3], [4, 4], [5, 5], [6, 6], [7, 7]]
    assert (tmp_path / 'references.csv').read_text().startswith('time,x,y,z,a,c\n')
    refused = subprocess.run([exe, 'plan', str(path), '--machine', 'trt_5axis', '--out', str(tmp_path),
                              '--feed', '0.01'], capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and 'its F words are the feeds' in refused.stderr
    bad = tmp_path / 'bad.ngc'
    bad.write_text('G0 X1\nG1 X2 F60\nG2 X3 R0.1\n')
    refused = subprocess.run([exe, 'plan', str(bad), '--out', str(tmp_path)], capture_output=True, text=True,
                             timeout=60)
    assert refused.returncode == 2 and f'{bad}:3: R 0.1' in refused.stderr, refused.stderr


def test_send_refuses_a_bad_program_before_it_looks_for_the_graph(tmp_path):
    bad = tmp_path / 'bad.ngc'
    bad.write_text('G0 X1\nG1 X2 F60 B3\n')
    exe = str(Path(sys.executable).parent / 'machine-ctrl')
    refused = subprocess.run([exe, 'send', str(bad), '--machine', 'trt_5axis'], capture_output=True, text=True,
                             timeout=60)
    assert refused.returncode == 2, refused.stderr
    assert refused.stderr == f'machine-ctrl: send: {bad}:2: trt_5axis has no rotary axis for B (its rotary axes: a c)\n'


def test_a_program_out_of_stroke_is_refused_naming_its_piece(tmp_path, micromill):
    far = tmp_path / 'far.ngc'
    far.write_text('G0 X1\nG1 X80 F600\n')
    result = plan_program(far, micromill)
    assert result.status == PlanStatus.OUT_OF_STROKE
    assert result.reason.startswith(f'{far}: line 2 (piece 2 of 2): '), result.reason


def test_a_program_text_as_the_topic_takes_it(circle_plan, trt):
    """trajectory.session.plan_program_text (the trajectory node's /trajectory/program, run in
    its planner process): the program's references one after the other; a bad program, or an
    M0 before the last motion (nobody is there to go on on a topic), refused naming the line."""
    from trajectory.session import plan_program_text
    _, planned = circle_plan
    reference, failure = plan_program_text(trt, CIRCLE.replace('M30', 'M0\nM30'), '/trajectory/program')
    assert failure == ''                        # an M0 after the last motion stops nothing
    assert np.array_equal(reference.position, planned.reference().position)
    assert plan_program_text(trt, CIRCLE.replace('G1 X1', 'G1 X1 Q3'), '/p') == (
        None, '/p:6: Q3: the word Q is not supported')
    reference, failure = plan_program_text(trt, CIRCLE.replace('G1 Z0 F120', 'G1 Z0 F120\nM0'), '/p')
    assert reference is None and failure.startswith('/p:4: an M0 program stop follows this block'), failure
    assert plan_program_text(trt, '(nothing)\n', '/p') == (None, '/p: no motion in the program')
    reference, failure = plan_program_text(trt, 'G1 X500 F60\n', '/p')    # 0.5 m: beyond the x stroke
    assert reference is None and failure.startswith('/p: line 1 (piece 1 of 1): '), failure
