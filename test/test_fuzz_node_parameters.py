"""Property-based fuzzing of the parameters of the nodes outside the graph ([6/8] item 4):
the recorder, the reference source, the replay and the view. test_fuzz_graph.py fuzzes
the parameter services of the seven graph nodes; these four ship as executables too
(`ros2 run`, bringup's recorder, `machine-ctrl replay` and `view`), offer the same
rcl_interfaces services and so take the same hostile requests. Each runs as its own
process (real DDS, the session's ROS domain) with the least it needs to come up: the
recorder a bag directory to create (it records every topic of the domain, its default),
the reference node its machine, the view any free port, the replay a small bag of its
own, looped (its topics and clock in a namespace of their own, so that nothing else
reads them).

Each node's parameters are discovered through its services (list, describe, get), then
hypothesis draws parameter sets with the graph campaign's strategies and oracle
(fuzz_cases.parameter_case: unknown names, NOT_SET, the wrong type, read-only ones, a
sim-time node's use_sim_time false, the live ones as they are) plus this module's own:
a read-only parameter set to its own value, and the only parameter of these nodes a
caller may change, rclpy's use_sim_time on the three that do not run on hw_sim's clock
(set back after). Each set goes through set_parameters or set_parameters_atomically.
Properties: the answer is the oracle's; a refusal has a reason and changes nothing (read
back), an accepted value reads back; no node process ends and no node logs a traceback;
a parameter of a type outside the enum (type 200) and a parameter named '' are refused
with the reason.

Found here (2026-12-07): the replay node offered the services and answered none (it
played its bag in its own loop and no executor ran: `ros2 param list /replay` timed out);
it answers from a thread of its own since (ReplayNode.run).

Size: MACHINE_CTRL_FUZZ_EXAMPLES as in test_fuzz_graph.py (default 300, the CI slice:
EXAMPLES = max(40, 300 // 5) = 60 requests of 1-3 parameters per node, the module about
20 s on two cores; `MACHINE_CTRL_FUZZ_EXAMPLES=2000`: 400 per node, about a minute);
derandomized unless MACHINE_CTRL_FUZZ_SEED gives a seed; MACHINE_CTRL_FUZZ_REPORT=FILE
writes the counts (parameters accepted and refused, per node and kind) as JSON.

Waiting: on conditions only (a ready line, a service ready, an answer, a count of
replayed messages); the timeouts bound failures.
"""
from __future__ import annotations

import json
import re
import threading
import time
from collections import Counter

import pytest
from hypothesis import given
from hypothesis import strategies as st

import fuzz_cases as fc
from machine_ctrl import parameters as tables
from machine_ctrl.app.processes import Supervisor
from machine_ctrl.ros.graph import NodeSpec
from ros_fixtures import private_context
from test_fuzz_graph import MESSAGES, REPORT, fuzz_settings

EXAMPLES = max(40, MESSAGES // 5)           # parameter requests per node
REPLAY_NAMESPACE = '/fuzz_replay'           # the replayed bag's topics and clock: read by nobody else
REPLAYED = f'{REPLAY_NAMESPACE}/replayed'
REPLAY_MESSAGES, REPLAY_SPACING = 10, 10_000_000    # per pass; ns of log time between them
ANSWER_TIMEOUT = 30.0                       # s: bounds a failure only
NODES = ('recorder', 'reference', 'view', 'replay')
EXECUTABLES = {'recorder': 'recorder_node', 'reference': 'reference_node', 'view': 'view_node',
               'replay': 'replay_node'}
TABLE_NAMES = {node: tables.table(executable).names for node, executable in EXECUTABLES.items()}
READY_LINES = {'recorder': 'recording to', 'reference': 'ready:', 'view': 'ready:'}
SERVICES = {'list': 'list_parameters', 'describe': 'describe_parameters', 'get': 'get_parameters',
            'set': 'set_parameters', 'atomic': 'set_parameters_atomically'}


def replay_bag(directory) -> None:
    """REPLAY_MESSAGES std_msgs/String on REPLAYED, REPLAY_SPACING apart (a pass of 0.1 s),
    in the namespace REPLAY_NAMESPACE: the replay's derived clock goes there too."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    from machine_ctrl.recording.bag import BagWriter, qos_profile
    from machine_ctrl.recording.recorder import NAMESPACE_KEY
    writer = BagWriter(directory)
    writer.add_topic(REPLAYED, 'std_msgs/msg/String', [qos_profile(depth=REPLAY_MESSAGES)])
    for i in range(REPLAY_MESSAGES):
        writer.write(REPLAYED, serialize_message(String(data=f'fuzz {i}')), 10**9 + i * REPLAY_SPACING)
    writer.close({NAMESPACE_KEY: REPLAY_NAMESPACE})


def node_specs(machine, directory) -> list[NodeSpec]:
    bag = directory / 'replayed'
    replay_bag(bag)
    return [
        NodeSpec('recorder', 'machine_ctrl.ros.recorder_node', 'RecorderNode',
                 {'output': str(directory / 'recording'), 'machine': machine.name}),
        NodeSpec('reference', 'machine_ctrl.ros.reference_node', 'ReferenceNode', {'machine': machine.name}),
        NodeSpec('view', 'machine_ctrl.ros.view_node', 'ViewNode', {'machine': machine.name, 'port': 0}),
        NodeSpec('replay', 'machine_ctrl.ros.replay_node', 'ReplayNode', {'bag': str(bag), 'loop': True}),
    ]


@pytest.fixture(scope='module')
def nodes(micromill, ros_env, tmp_path_factory):
    directory = tmp_path_factory.mktemp('fuzz-node-parameters')
    with Supervisor(ros_env, log_dir=directory / 'logs', stop_timeout=3.0) as supervisor:
        supervisor.start_nodes(node_specs(micromill, directory), params_dir=directory)
        for name, line in READY_LINES.items():
            supervisor.wait_for_line(name, line, timeout=120)
        yield supervisor


class Probe:
    """The test's node: a client of every node's parameter services, and a reader of the
    replayed bag (the replay's sign of life)."""

    def __init__(self, context, supervisor):
        import rclpy
        from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String

        self.supervisor = supervisor
        self.node = rclpy.create_node('fuzz_parameters_probe', context=context)
        self.kinds = {'list': ListParameters, 'describe': DescribeParameters, 'get': GetParameters,
                      'set': SetParameters, 'atomic': SetParametersAtomically}
        self.services = {(n, k): self.node.create_client(kind, f'/{n}/{SERVICES[k]}')
                         for n in NODES for k, kind in self.kinds.items()}
        self.replayed = 0
        self.node.create_subscription(String, REPLAYED, self.on_replayed,
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self._declared: dict[str, dict[str, fc.Declared]] = {}
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.running = True
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.thread.start()

    def spin(self) -> None:
        while self.running:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.running = False
        self.thread.join(timeout=2)
        self.executor.shutdown()
        self.node.destroy_node()

    def on_replayed(self, _msg) -> None:
        self.replayed += 1

    def wait(self, condition, what: str, timeout: float = ANSWER_TIMEOUT) -> None:
        """Until `condition()`; a node process that ended fails at once (Supervisor.check)."""
        deadline = time.monotonic() + timeout
        while not condition():
            self.supervisor.check()
            assert time.monotonic() < deadline, f'no {what} within {timeout:g} s'
            time.sleep(0.01)

    def call(self, node: str, kind: str, request):
        service = self.services[(node, kind)]
        assert service.wait_for_service(timeout_sec=ANSWER_TIMEOUT), f'/{node}/{SERVICES[kind]} not offered'
        future = service.call_async(request)
        self.wait(future.done, f'answer of /{node}/{SERVICES[kind]}')
        return future.result()

    def get(self, node: str, names) -> dict:
        from rclpy.parameter import parameter_value_to_python
        answer = self.call(node, 'get', self.kinds['get'].Request(names=list(names)))
        assert len(answer.values) == len(names), (node, names, answer)
        return {n: fc.plain(parameter_value_to_python(v)) for n, v in zip(names, answer.values)}

    def names(self, node: str) -> list[str]:
        return list(self.call(node, 'list', self.kinds['list'].Request()).result.names)

    def declared(self, node: str) -> dict[str, fc.Declared]:
        """What list, describe and get say of every parameter of `node` (test_fuzz_graph's
        Parameters.discover, for any node), once."""
        if node not in self._declared:
            names = self.names(node)
            descriptors = self.call(node, 'describe', self.kinds['describe'].Request(names=names)).descriptors
            values = self.get(node, names)
            self._declared[node] = {d.name: fc.Declared.of(d, values[d.name]) for d in descriptors}
        return self._declared[node]

    def set(self, node: str, parameters, atomically: bool):
        """The result of each parameter (atomically: the one result, for each)."""
        if atomically:
            result = self.call(node, 'atomic', self.kinds['atomic'].Request(parameters=parameters)).result
            return [result] * len(parameters)
        return list(self.call(node, 'set', self.kinds['set'].Request(parameters=parameters)).results)


@pytest.fixture(scope='module')
def probe(nodes, ros_env):
    with private_context(ros_env) as context:
        p = Probe(context, nodes)
        try:
            # the replay is up once its bag comes (it printed nothing)
            p.wait(lambda: p.replayed >= REPLAY_MESSAGES, 'replayed message', timeout=120)
            yield p
        finally:
            p.close()


@pytest.fixture(scope='module')
def books():
    """(node, kind, outcome) -> parameters set; printed (and MACHINE_CTRL_FUZZ_REPORT) at the end."""
    counts = Counter()
    started = time.monotonic()
    yield counts
    report = {'examples_per_node': EXAMPLES, 'seconds': round(time.monotonic() - started, 1),
              'parameter_sets': {f'{n} {k} {o}': c for (n, k, o), c in sorted(counts.items())},
              'per_node': {n: {o: sum(c for (m, _, p), c in counts.items() if m == n and p == o)
                               for o in ('accepted', 'refused')} for n in NODES}}
    print('\nnode parameter campaign:', json.dumps(report, indent=1))
    if REPORT:
        with open(REPORT, 'w') as f:
            json.dump(report, f, indent=1)


def assert_running(nodes, node) -> None:
    nodes.check()
    assert node in nodes.alive(), node


# -- the strategies of this module --------------------------------------------------------------
# use_sim_time is the only parameter of these nodes a caller may change (every table entry is
# read-only); a node not on hw_sim's clock takes either value. The reference node runs on it:
# fuzz_cases' 'sim time off' and 'no-op' cover it.
VALID = {node: {'use_sim_time': st.booleans()} for node in ('recorder', 'view', 'replay')}


@st.composite
def valid_case(draw, node: str, declared: dict[str, fc.Declared]):
    name, values = draw(st.sampled_from(sorted(VALID[node].items())))
    return fc.ParameterCase(node, 'valid', name, declared[name].type, draw(values), 'accepted')


@st.composite
def read_only_as_is(draw, node: str, declared: dict[str, fc.Declared]):
    """A read-only parameter set to the value it has: refused all the same (rclpy)."""
    d = draw(st.sampled_from(sorted((d for d in declared.values() if d.read_only), key=lambda d: d.name)))
    return fc.ParameterCase(node, 'read-only as is', d.name, d.type, d.value, 'refused')


def node_case(node: str, declared: dict[str, fc.Declared], sim_time: bool):
    """The graph campaign's cases (fuzz_cases.parameter_case: five or six kinds here) or one
    of this module's kinds, each about as often."""
    own = [read_only_as_is(node, declared)] + ([valid_case(node, declared)] if node in VALID else [])
    theirs = fc.parameter_case(node, declared, sim_time)
    return st.sampled_from(range(6 + len(own))).flatmap(lambda i: own[i - 6] if i >= 6 else theirs)


def check_set(probe, books, node, declared, cases, atomically) -> None:
    """Send `cases` in one request; assert the oracle's answers, the read-back, and set the
    accepted valid ones back."""
    known = [c.name for c in cases if c.name in declared]
    before = probe.get(node, known)
    results = probe.set(node, [c.message() for c in cases], atomically)
    after = probe.get(node, known)
    assert len(results) == len(cases), (node, len(results), len(cases))
    expect_all = 'accepted' if all(c.expect == 'accepted' for c in cases) else 'refused'
    for case, result in zip(cases, results):
        expect = expect_all if atomically else case.expect
        books[(node, case.kind, fc.check_parameter_answer(node, case, result, expect, declared, before, after))] += 1
    restore = [fc.ParameterCase(node, 'restore', c.name, declared[c.name].type, before[c.name], 'accepted').message()
               for c, r in zip(cases, results) if r.successful and c.kind == 'valid']
    if restore:
        assert all(r.successful for r in probe.set(node, restore, atomically=False)), (node, restore)


# -- the campaign ------------------------------------------------------------------------------
@pytest.mark.parametrize('node', NODES)
def test_parameter_sets_are_refused_with_the_reason_or_taken_and_read_back(nodes, probe, books, node):
    """Every parameter of the node's table is among those discovered; each drawn request gets
    the oracle's answers (test_fuzz_graph's properties), the node runs on, and at the end
    every parameter has the value it had at the start."""
    declared = probe.declared(node)
    assert set(TABLE_NAMES[node]) <= set(declared), (node, sorted(declared))      # the whole table fuzzed
    sim_time = 'use_sim_time' in declared and declared['use_sim_time'].value is True
    requests = st.lists(node_case(node, declared, sim_time), min_size=1, max_size=3, unique_by=lambda c: c.name)

    @fuzz_settings(EXAMPLES)
    @given(cases=requests, atomically=st.booleans())
    def campaign(cases, atomically):
        check_set(probe, books, node, declared, cases, atomically)
        assert_running(nodes, node)

    campaign()
    assert probe.get(node, list(declared)) == {n: d.value for n, d in declared.items()}, node    # all as at start


# -- requests rclpy itself mishandles ---------------------------------------------------------
@pytest.mark.parametrize('node', NODES)
def test_a_parameter_of_a_type_outside_the_enum_is_refused_with_the_reason(nodes, probe, node):
    """As test_fuzz_graph's, on a declared parameter of each node (the first of its table):
    set_parameters refuses that one alone (the request's other is set), set_parameters_atomically
    the whole request (nothing set)."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    name = TABLE_NAMES[node][0]
    bad = Parameter(name=name, value=ParameterValue(type=200))
    reason = f"parameter '{name}': type 200 is not a ParameterType (0-9)"
    before = probe.get(node, [name, 'use_sim_time'])
    good = Parameter(name='use_sim_time', value=ParameterValue(type=ParameterType.PARAMETER_BOOL,
                                                               bool_value=before['use_sim_time']))   # as it is
    one, other = probe.set(node, [bad, good], atomically=False)
    assert (one.successful, one.reason) == (False, reason), (node, one)
    assert other.successful, (node, other)
    whole = probe.set(node, [good, bad], atomically=True)[0]
    assert (whole.successful, whole.reason) == (False, reason), (node, whole)
    assert probe.get(node, [name, 'use_sim_time']) == before, node
    assert_running(nodes, node)


@pytest.mark.parametrize('node, atomically', [(n, a) for n in NODES for a in (False, True)])
def test_an_empty_parameter_name_is_refused(nodes, probe, node, atomically):
    """rclpy lets '' through its undeclared-name check (test_fuzz_graph): node_parameters
    refuses it on every node that declares its parameters there, and none is created."""
    case = fc.ParameterCase(node, 'unknown', '', fc.BOOL, True, 'refused')
    (result,) = probe.set(node, [case.message()], atomically)
    assert not result.successful and result.reason.strip(), (node, result)
    assert '' not in probe.names(node), node
    assert_running(nodes, node)


# -- what the campaign reached -----------------------------------------------------------------
def test_the_campaign_reached_every_kind_and_no_node_failed(nodes, probe, books):
    """Last of the module: every node took sets and refused sets, of every kind its
    parameters allow; every node process runs, none logged a traceback."""
    for node in NODES:
        outcomes = {o for (n, _, o) in books if n == node}
        assert outcomes == {'accepted', 'refused'}, (node, outcomes)
        kinds = {k for (n, k, _) in books if n == node}
        wanted = {'unknown', 'unset', 'no-op', 'read-only', 'wrong type', 'read-only as is'}
        wanted |= {'valid'} if node in VALID else {'sim time off'}
        assert kinds >= wanted, (node, wanted - kinds)
    nodes.check()
    assert set(nodes.alive()) == set(NODES), nodes.alive()
    for node in NODES:
        log = nodes[node].log_path.read_text(errors='replace')
        assert not re.search(r'Traceback|callback failed', log), (node, log[-3000:])
