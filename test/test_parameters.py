"""Declared parameters (machine_ctrl/parameters.py): every node declares its table with
descriptors, refuses a bad override at start with one line (exit 2) and a bad set with the
reason; the README table is the table; node specs are typed data (parameters files, the
single-process specs file)."""
import math
import re
from pathlib import Path

import pytest
import yaml

from machine_ctrl import parameters
from machine_ctrl.parameters import ParameterSpec, validate

README = Path(__file__).resolve().parents[1] / 'README.md'

# rcl_interfaces/ParameterType values
ROS_TYPE = {'bool': 1, 'integer': 2, 'double': 3, 'string': 4, 'double_array': 8, 'string_array': 9}

NODES = {   # executable -> (module, class)
    'hw_sim_node': ('machine_ctrl.ros.hw_sim_node', 'HwSimNode'),
    'servo_node': ('machine_ctrl.ros.servo_node', 'ServoNode'),
    'dual_stage_node': ('machine_ctrl.ros.dual_stage_node', 'DualStageNode'),
    'reference_node': ('machine_ctrl.ros.reference_node', 'ReferenceNode'),
    'trajectory_node': ('machine_ctrl.ros.trajectory_node', 'TrajectoryNode'),
    'compensation_node': ('machine_ctrl.ros.compensation_node', 'CompensationNode'),
    'contour_error_node': ('machine_ctrl.ros.contour_error_node', 'ContourErrorNode'),
    'recorder_node': ('machine_ctrl.ros.recorder_node', 'RecorderNode'),
    'replay_node': ('machine_ctrl.ros.replay_node', 'ReplayNode'),
}


def node_class(executable):
    module, cls = NODES[executable]
    return getattr(__import__(module, fromlist=[cls]), cls)


def destroy(node, code):
    """Destroy a node; one that ended in its constructor with the plain Node method."""
    from rclpy.node import Node
    (Node.destroy_node if code is not None else type(node).destroy_node)(node)


def make_node(executable, context, overrides):
    """(node, exit code): the node object even when its constructor ended with SystemExit
    (it declared its parameters before)."""
    from rclpy.parameter import Parameter
    cls = node_class(executable)
    node = cls.__new__(cls)
    try:
        node.__init__(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
    except SystemExit as exc:
        return node, exc.code
    return node, None


# --- the tables, ROS-free -------------------------------------------------------------------

@pytest.mark.parametrize('spec, value, reason', [
    (ParameterSpec('t', 'double', 0.5, 's', low=0.0, low_open=True), 0.0, 'must be > 0 s, got 0.0'),
    (ParameterSpec('t', 'double', 0.5, 's', low=0.0, low_open=True), 1, 'must be a floating-point number (e.g. 1.0, not 1), got integer 1'),
    (ParameterSpec('t', 'double', 0.5, 's', low=0.0, low_open=True), math.inf, 'must be finite, got inf'),
    (ParameterSpec('r', 'double', 0.1, low=0.0, high=1.0, low_open=True), 1.5, 'must be in (0, 1], got 1.5'),
    (ParameterSpec('n', 'integer', 10, 'steps', low=1), 0, 'must be >= 1 steps, got 0'),
    (ParameterSpec('n', 'integer', 10, 'steps', low=1), True, 'must be an integer, got bool True'),
    (ParameterSpec('m', 'string', 'a', choices=('a', 'b', 'c')), 'd', "must be a, b or c, got 'd'"),
    (ParameterSpec('p', 'string', '', description='a file', required=True), '', 'missing: a file'),
    (ParameterSpec('q', 'double_array', [0.0]), [0.0, float('nan')], 'must be finite, got [0.0, nan]'),
    (ParameterSpec('s', 'string_array', ['']), ['a', 1], "must be a list of strings, got ['a', 1]"),
])
def test_validate_gives_the_reason(spec, value, reason):
    assert validate(spec, value) == reason


@pytest.mark.parametrize('spec, value', [
    (ParameterSpec('t', 'double', 0.5, 's', low=0.0, low_open=True), 1e-9),
    (ParameterSpec('r', 'double', 0.1, low=0.0, high=1.0, low_open=True), 1.0),
    (ParameterSpec('n', 'integer', 10, low=0), 0),
    (ParameterSpec('b', 'bool', True), False),
])
def test_validate_accepts_values_in_range(spec, value):
    assert validate(spec, value) is None


def test_table_defaults_are_those_of_the_cores():
    from machine_ctrl.contour.estimation import ESTIMATORS
    from machine_ctrl.model.config import DEFAULT_MACHINE
    from trajectory.planner import DEFAULT_FEED
    assert parameters.TRAJECTORY.spec('feed').default == DEFAULT_FEED
    assert parameters.CONTOUR_ERROR.spec('estimator').choices == ESTIMATORS
    assert parameters.HW_SIM.spec('machine').default == DEFAULT_MACHINE


def test_reference_node_contours_are_those_of_trajectory_contours(micromill):
    """Each choice plays (contour_reference), and contour_reference knows no other name: its
    refusal lists exactly the choices."""
    from trajectory.contours import contour_reference
    choices = parameters.REFERENCE.spec('contour').choices
    for name in choices:
        assert len(contour_reference(micromill, name)) > 0, name
    with pytest.raises(ValueError) as refused:
        contour_reference(micromill, 'triangle')
    known = re.fullmatch(r"contour must be (.+) or (\w+), got 'triangle'", str(refused.value))
    assert known and sorted([*known[1].split(', '), known[2]]) == sorted(choices), str(refused.value)


def _readme_rows():
    text = README.read_text()
    section = text[text.index('## Node parameters'):]
    section = section[:section.index('\n## ', 5)]
    rows = []
    for line in section.splitlines():
        if line.startswith('| `'):
            cells = [c.strip() for c in re.split(r'(?<!\\)\|', line)[1:-1]]
            rows.append(tuple(c.replace('\\|', '|').strip('`') for c in cells))
    return rows


def test_readme_table_is_the_declared_table():
    rows = _readme_rows()
    declared = [row for table in parameters.TABLES for row in parameters.readme_rows(table)]
    assert [r[:2] for r in rows] == [d[:2] for d in declared]          # every parameter, once, in order
    for row, table_row in zip(rows, declared):
        assert row == table_row, row[:2]
    assert len(rows) == sum(len(t.parameters) for t in parameters.TABLES)


# --- the nodes ------------------------------------------------------------------------------

@pytest.fixture
def node_arguments(micromill, tmp_path):
    """Overrides a node needs to start at all (beside its defaults)."""
    return {
        'compensation_node': {'model': str(micromill.simulation.error_map_path(micromill.yaml_path))},
        'recorder_node': {'output': str(tmp_path / 'bag')},
        'replay_node': {'bag': str(tmp_path / 'no_bag')},      # ends after declaring: no such bag
    }


def declared_specs(node, table):
    """(spec, name) of every parameter the node declared from `table`: a template's
    instances with their own specs (the node's declarations), the others by name."""
    from machine_ctrl.ros.node_parameters import gain_parameters
    out = []
    for spec in table.parameters:
        if not spec.template:
            out.append((spec, spec.name))
            continue
        instances = [n for n in node._parameters if spec.matches(n)]
        assert table is parameters.SERVO and spec.name == 'gains.<axis>.<gain>'
        gains = gain_parameters(node.machine, node.axes)
        assert sorted(instances) == sorted(g.name for g in gains) and instances, instances
        out += [(g.spec, g.name) for g in gains]
    return out


@pytest.mark.parametrize('spec, text', [
    (ParameterSpec('t', 'double', 0.5, 's', low=0.0, low_open=True), '> 0'),
    (ParameterSpec('n', 'integer', 10, low=1), '>= 1'),
    (ParameterSpec('f', 'double', 0.5, low=0.0, high=1.0, low_open=True), '(0, 1]'),
    (ParameterSpec('f', 'double', 0.5, low=0.0, high=1.0, high_open=True), '[0, 1)'),
    (ParameterSpec('g', 'double', 1.0, high=2.5e-3), '<= 0.0025'),
    (ParameterSpec('x', 'double', 1.0), 'finite'),
    (ParameterSpec('m', 'string', 'a', choices=('a', 'b')), 'one of a, b'),
    (ParameterSpec('p', 'string', '', required=True), 'non-empty'),
    (ParameterSpec('s', 'string', '', constraint='a ROS namespace'), 'a ROS namespace'),
    (ParameterSpec('b', 'bool', True), ''),
])
def test_the_range_column_in_words(spec, text):
    """The words of the README's range column and of each descriptor's
    additional_constraints (test_every_declared_parameter_has_its_descriptor compares the
    nodes' descriptors with these), written out here."""
    assert parameters.range_text(spec) == text


@pytest.mark.parametrize('executable', list(NODES))
def test_every_declared_parameter_has_its_descriptor(executable, rclpy_context, node_arguments):
    table = parameters.table(executable)
    node, code = make_node(executable, rclpy_context, node_arguments.get(executable, {}))
    try:
        assert code == (2 if executable == 'replay_node' else None)
        if code is None:        # the nodes on the simulated clock are the table's
            assert node.get_parameter('use_sim_time').value is table.sim_time
            if table.sim_time:
                assert parameters.SIM_TIME_REASON in node.describe_parameter('use_sim_time').description
        for spec, name in (declared_specs(node, table) if code is None else [(s, s.name) for s in table]):
            if spec.template:
                continue
            assert spec.name == name and node.has_parameter(spec.name), spec.name
            d = node.describe_parameter(spec.name)
            assert d.type == ROS_TYPE[spec.type], spec.name
            assert d.read_only == (not spec.live), spec.name
            assert d.description.startswith(spec.description), spec.name
            if spec.unit:
                assert d.description.endswith(f'[{spec.unit}]'), spec.name
            assert d.additional_constraints == parameters.constraint_text(table, spec) or spec.name.startswith('gains.'), spec.name
            if spec.type == 'double' and (spec.low is not None or spec.high is not None):
                (r,) = d.floating_point_range
                assert (r.from_value, r.to_value) == (spec.low if spec.low is not None else -1.7976931348623157e308,
                                                      spec.high if spec.high is not None else 1.7976931348623157e308)
            else:
                assert not d.floating_point_range, spec.name
            if spec.type == 'integer' and (spec.low is not None or spec.high is not None):
                (r,) = d.integer_range
                assert (r.from_value, r.to_value) == (spec.low if spec.low is not None else -2 ** 63,
                                                      spec.high if spec.high is not None else 2 ** 63 - 1)
            else:
                assert not d.integer_range, spec.name
            if spec.default is not None and spec.name not in node_arguments.get(executable, {}):
                assert node.get_parameter(spec.name).value == spec.default, spec.name
    finally:
        destroy(node, code)


START_REFUSALS = [
    ('hw_sim_node', {'mode': 'turbo'}, "parameter mode: must be lockstep or paced, got 'turbo'"),
    ('hw_sim_node', {'real_time_factor': 0.0}, 'parameter real_time_factor: must be in (0, 1], got 0.0'),
    ('hw_sim_node', {'clock_decimation': 0}, 'parameter clock_decimation: must be >= 1 steps, got 0'),
    ('hw_sim_node', {'mode': 'paced', 'recorder_window': 10},
     'parameter recorder_window: needs mode lockstep (0 with mode paced), got 10'),
    ('hw_sim_node', {'mode': 'turbo', 'command_timeout': -1.0},
     "parameters: mode: must be lockstep or paced, got 'turbo'; command_timeout: must be > 0 s, got -1.0"),
    ('servo_node', {'input_timeout': 0.0}, 'parameter input_timeout: must be > 0 s, got 0.0'),
    ('servo_node', {'wait_for_offsets': 1}, 'parameter wait_for_offsets: must be true or false, got integer 1'),
    ('servo_node', {'axes': ['x_c', 'q']}, 'parameter axes: must name controlled axes of micromill_9axis '
     "(x_c, y_c, z_c, x_f, y_f, z_f, a_f, b_f, c_f), each once; unknown 'q'"),
    ('servo_node', {'axes': ['x_c', 'y_c', 'x_c']}, 'parameter axes: must name controlled axes of micromill_9axis '
     '(x_c, y_c, z_c, x_f, y_f, z_f, a_f, b_f, c_f), each once; repeated x_c'),
    ('servo_node', {'use_sim_time': False}, "parameter use_sim_time: this node runs on hw_sim's simulated clock "
     '(topic clock, design.md "Time"); it cannot be switched off, got false'),
    ('servo_node', {'gains.x_c.gain': 0.0}, 'parameter gains.x_c.gain: must be > 0 V*s/m (V*s/rad), got 0.0'),
    ('servo_node', {'gains.x_c.gain': 5000.0}, 'parameter gains.x_c: gain: T (K_s / m_e + lambda) = 1.09 must be < 1 '
     '(the sampled loop would oscillate or diverge; K_s 5000, lambda 200, m_e 0.4667, T 0.0001)'),
    ('servo_node', {'belief': ['/nonexistent/x_c.yaml']}, '/nonexistent/x_c.yaml: cannot read: [Errno 2] No such file '
     "or directory: '/nonexistent/x_c.yaml'"),
    ('dual_stage_node', {'dual_stage': 'no'}, "parameter dual_stage: must be true or false, got string 'no'"),
    ('reference_node', {'chunk_steps': 600, 'lookahead_steps': 500},
     'parameter lookahead_steps: must be >= chunk_steps (600), got 500'),
    ('trajectory_node', {'feed': 1}, 'parameter feed: must be a floating-point number (e.g. 1.0, not 1), got integer 1'),
    ('trajectory_node', {'feed': -0.01}, 'parameter feed: must be > 0 m/s, got -0.01'),
    ('trajectory_node', {'chunk_steps': 500, 'lookahead_steps': 900},
     'parameter lookahead_steps: must be >= 2 x chunk_steps (1000), got 900'),
    ('trajectory_node', {'lookahead_steps': 5000}, 'parameter lookahead_steps: must be <= 49 x chunk_steps (4900: a '
     'late reader gets the last 50 chunks), got 5000'),
    ('reference_node', {'chunk_steps': 10}, 'parameter lookahead_steps: must be <= 49 x chunk_steps (490: a late '
     'reader gets the last 50 chunks), got 3000'),
    ('compensation_node', {}, 'parameter model: missing: geometric error model YAML (machine-ctrl fit-errors --out)'),
    ('contour_error_node', {'estimator': 'fancy'},
     "parameter estimator: must be basic, shifted or compensated, got 'fancy'"),
    ('recorder_node', {'output': 'x', 'duration': -1.0}, 'parameter duration: must be >= 0 s, got -1.0'),
    ('recorder_node', {'output': 'x', 'start_streams': 2, 'topics': ['/joint_states']},
     'parameter start_streams: needs every topic recorded (topics empty), got 2'),
    ('replay_node', {'bag': 'x', 'rate': 0.0}, 'parameter rate: must be > 0, got 0.0'),
]


@pytest.mark.parametrize('executable, overrides, line', START_REFUSALS)
def test_a_bad_override_ends_the_node_with_one_line(executable, overrides, line, rclpy_context, capfd):
    node, code = make_node(executable, rclpy_context, overrides)
    destroy(node, code)
    assert code == 2
    fatal = [text for text in capfd.readouterr().err.splitlines() if 'FATAL' in text]
    assert len(fatal) == 1 and fatal[0].endswith(line), fatal


def test_sets_are_checked_live_ones_take_effect(rclpy_context):
    from rclpy.parameter import Parameter
    node, code = make_node('trajectory_node', rclpy_context, {})
    try:
        assert code is None

        def set_one(name, value):
            (result,) = node.set_parameters([Parameter(name, value=value)])
            return result
        refused = set_one('feed', 0.0)                          # in the descriptor's range, refused by the table
        assert not refused.successful and refused.reason == 'feed: must be > 0 m/s, got 0.0'
        refused = set_one('feed', -0.5)                         # outside the descriptor's range: rclpy refuses
        assert not refused.successful and 'out of range' in refused.reason
        refused = set_one('feed', 'fast')
        assert not refused.successful and 'Wrong parameter type' in refused.reason
        assert node.feed == 0.01 and node.get_parameter('feed').value == 0.01
        assert set_one('feed', 0.02).successful                 # live: the next path is planned at 0.02 m/s
        assert node.feed == 0.02
        refused = set_one('chunk_steps', 200)                   # read once at start
        assert not refused.successful and refused.reason == 'Trying to set a read-only parameter: chunk_steps.'
    finally:
        node.destroy_node()


# --- node specs as data -------------------------------------------------------------------------

def test_node_specs_are_typed_and_checked(micromill):
    from machine_ctrl.ros.graph import NodeSpec, default_graph
    spec = NodeSpec('hw_sim', 'machine_ctrl.ros.hw_sim_node', 'HwSimNode', {'initial_position': [0, 1, 0.5]})
    assert spec.parameters['initial_position'] == [0.0, 1.0, 0.5]
    assert all(type(v) is float for v in spec.parameters['initial_position'])
    with pytest.raises(ValueError, match="hw_sim: parameter mode: must be lockstep or paced, got 'fast'"):
        NodeSpec('hw_sim', 'machine_ctrl.ros.hw_sim_node', 'HwSimNode', {'mode': 'fast'})
    with pytest.raises(ValueError, match="servo: servo_node has no parameter 'enabled'"):
        NodeSpec('servo', 'machine_ctrl.ros.servo_node', 'ServoNode', {'enabled': True})
    for dual in (True, False):          # one name for the switch, everywhere
        (spec,) = [s for s in default_graph(micromill, dual_stage=dual) if s.name == 'dual_stage']
        assert spec.parameters == {'machine': str(micromill.yaml_path), 'dual_stage': dual}


def test_bringup_gives_the_belief_files_to_the_servo_nodes_only(micromill, tmp_path, monkeypatch):
    """`machine-ctrl bringup --identified FILE`: the servos' `belief`, as an absolute path (the
    nodes may run elsewhere in the file system); hw_sim and the others keep the machine's."""
    from machine_ctrl.app.bringup import graph_specs
    monkeypatch.chdir(tmp_path)
    specs = {s.name: s.parameters for s in graph_specs(micromill, belief=['x_c.yaml'])}
    assert specs['servo_coarse']['belief'] == specs['servo_fine']['belief'] == [str(tmp_path / 'x_c.yaml')]
    assert [name for name, parameters in specs.items() if 'belief' in parameters] == ['servo_coarse', 'servo_fine']


def test_specs_file_and_parameters_file_keep_the_values(micromill, tmp_path):
    from machine_ctrl.app.bringup import graph_specs
    from machine_ctrl.ros.graph import read_specs, write_params_file, write_specs
    specs = graph_specs(micromill, dual_stage=False, record=True)
    assert read_specs(write_specs(specs, tmp_path / 'graph.yaml')) == specs
    document = yaml.safe_load(write_params_file(specs, tmp_path).read_text())
    assert document['/dual_stage'] == {'ros__parameters': {'machine': str(micromill.yaml_path), 'dual_stage': False}}
    hw_sim = document['/hw_sim']['ros__parameters']
    assert (hw_sim['min_subscribers'], hw_sim['recorder_window']) == (5, 100)   # 2 servos, dual_stage, contour_error, recorder
    assert document['/servo_fine']['ros__parameters']['axes'] == ['x_f', 'y_f', 'z_f', 'a_f', 'b_f', 'c_f']


def test_a_node_reads_its_spec_from_the_parameters_file(micromill, ros_env, tmp_path):
    import rclpy
    from rclpy.context import Context

    from machine_ctrl.ros.graph import NodeSpec
    from machine_ctrl.ros.servo_node import ServoNode
    spec = NodeSpec('servo_fine', 'machine_ctrl.ros.servo_node', 'ServoNode',
                    {'machine': str(micromill.yaml_path), 'axes': ['x_f', 'y_f'], 'input_timeout': 1.0})
    argv = spec.argv(tmp_path)
    assert argv[-2] == '--params-file'
    context = Context()
    rclpy.init(args=['servo', *argv[argv.index('--ros-args'):]], context=context,
               domain_id=int(ros_env['ROS_DOMAIN_ID']))
    try:
        node = ServoNode(name='servo_fine', context=context)
        try:
            assert node.get_parameter('axes').value == ['x_f', 'y_f']
            assert node.get_parameter('input_timeout').value == 1.0
            assert node.get_parameter('machine').value == str(micromill.yaml_path)
        finally:
            node.destroy_node()
    finally:
        context.try_shutdown()
