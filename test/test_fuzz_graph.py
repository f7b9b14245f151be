"""Property-based fuzzing of the running graph ([6/8] item 4): hypothesis draws hostile
messages of every type the nodes subscribe to, parameter sets of every node and service
calls in any order (test/fuzz_cases.py: the strategies and the oracle), and sends them to
the graph of test_robustness.py (hw_sim, servo_coarse, servo_fine, dual_stage,
trajectory, compensation, contour_error: each node its own process, real DDS, a ROS domain
of this session's own).

Properties: no node process ends; every invalid message is refused and counted, with a
reason, where the README says (/trajectory/status `rejected_goals` and `last_rejection`,
the nodes' /diagnostics `rejected_messages` / `rejected_chunks` / `refused_commands` with
`last_rejection` / `last_refusal`) — the counters reach exactly what the oracle predicts
(but for /clock: rclpy's clock reader keeps the newest message only, so a clock that is no
time counts at most once); a G-code program on /trajectory/program is read whole and refused
before anything of it is planned;
nothing moves while only invalid input is sent (ground-truth positions, the reference
stream); hw_sim does not fault; a parameter set is refused with the reason and changes
nothing, or is taken and read back; every service call is answered, a refusal with its
reason. By-design trust (a well-formed message on an internal topic is taken, whoever sends
it) is left out of the invalid campaign and checked for its documented outcome.

Size: MACHINE_CTRL_FUZZ_EXAMPLES topic messages (default 300: the CI slice; the long
campaign is `MACHINE_CTRL_FUZZ_EXAMPLES=10000 ./dev/test test/test_fuzz_graph.py`, or
bench/fuzz_graph.py, which prints the numbers); parameter sets and service sequences scale
with it. Examples are derandomized (the same every run) unless MACHINE_CTRL_FUZZ_SEED
gives a seed. MACHINE_CTRL_FUZZ_REPORT=FILE writes the campaign's numbers as JSON.

Waiting: on conditions only. A goal-topic message is sent once the previous one is
refused (its /trajectory/status is published at once); the per-step and reference topics
get at most BATCH messages at a time, fewer than any reader's keep-last depth (50 for
/reference, 200 for the per-step topics), then the test waits until every node's
/diagnostics counters (1 Hz) reach what the oracle predicts.
"""
from __future__ import annotations

import json
import math
import os
import re
import threading
import time
import uuid
from collections import Counter, deque

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st

import fuzz_cases as fc
from limit_checks import LINEAR_STILL, ROTARY_STILL
from machine_ctrl import contract
from machine_ctrl.app.client import MachineClient, Timeout
from machine_ctrl.app.processes import Supervisor
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.ros.graph import default_graph
from ros_fixtures import ProgressReporter, private_context

MESSAGES = int(os.environ.get('MACHINE_CTRL_FUZZ_EXAMPLES', '300'))
SEED = os.environ.get('MACHINE_CTRL_FUZZ_SEED')
REPORT = os.environ.get('MACHINE_CTRL_FUZZ_REPORT')
STEPWISE = bool(os.environ.get('MACHINE_CTRL_FUZZ_STEPWISE'))    # wait for each message's refusal: finds the one
BATCH = 30                   # topic messages per example: < every reader's keep-last depth
TOPIC_EXAMPLES = max(1, math.ceil(MESSAGES / BATCH))
PARAMETER_EXAMPLES = max(40, MESSAGES // 5)
SERVICE_EXAMPLES = max(10, MESSAGES // 25)
NODES = ('hw_sim', 'servo_coarse', 'servo_fine', 'dual_stage', 'trajectory', 'compensation', 'contour_error')


def fuzz_settings(examples: int):
    """Reproducible (derandomized, or MACHINE_CTRL_FUZZ_SEED), no deadline (a graph round
    trip), no database (nothing left in the checkout), no shrinking (each example costs
    graph time; the failing example is printed as drawn)."""
    decorate = settings(max_examples=examples, derandomize=SEED is None, deadline=None, database=None,
                        phases=(Phase.explicit, Phase.generate), print_blob=False,
                        suppress_health_check=(HealthCheck.too_slow, HealthCheck.data_too_large,
                                               HealthCheck.large_base_example, HealthCheck.filter_too_much))

    def apply(test):
        test = decorate(test)
        return seed(int(SEED))(test) if SEED is not None else test
    return apply


def graph_specs(machine):
    """test_robustness's graph; hw_sim runs at most ProgressReporter.WINDOW steps ahead of
    contour_error's estimates (the test reports them as a recorder would): contour_error is
    the one per-step reader hw_sim does not wait for, and behind a busy core its keep-last
    queue would drop states, the test's among them, uncounted."""
    model = str(machine.simulation.error_map_path(machine.yaml_path))
    return default_graph(machine, contour=None, compensation_model=model, contour_error=True,
                         hw_sim={'recorder_window': ProgressReporter.WINDOW})


class ReferenceWatch:
    """The /reference stream the servos follow: every row the same as the first one (the
    machine is held), or the first row that differs."""

    def __init__(self, clock):
        self.clock, self.lock = clock, threading.Lock()
        self.reset()

    def reset(self) -> None:
        with self.lock:
            self.first, self.rows, self.changed = None, 0, None

    def on_chunk(self, msg) -> None:
        try:
            first, positions, _, _ = ros_io.parse_chunk(self.clock, msg, fc.AXES)
        except ros_io.InvalidMessage:
            return                                   # a chunk of this test: refused by every reader too
        with self.lock:
            for i, row in enumerate(positions):
                if self.first is None:
                    self.first = row
                elif row != self.first and self.changed is None:
                    self.changed = (first + i, row, self.first)
                self.rows += 1


class FuzzClient(MachineClient):
    """The command API, a test-side publisher per subscribed topic, and what the test
    observes: every node's /diagnostics, the ground truth, the reference stream."""

    def __init__(self, node, machine):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String
        from trajectory_msgs.msg import JointTrajectory

        self.diagnostics, self.truth, self.history = {}, None, {}
        self.reference = ReferenceWatch(ros_io.StepClock.of(machine))
        deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(JointTrajectory, contract.REFERENCE.name, self.reference.on_chunk, deep)
        node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self.on_diagnostics, 1000)
        node.create_subscription(JointState, contract.TRUE_JOINT_STATES.name, self.on_truth, 10)
        self.progress = ProgressReporter(node, ros_io.StepClock.of(machine))
        node.create_subscription(Vector3Stamped, contract.CONTOUR_TOOL_TIP.name, self.on_estimate, ros_io.STEP_QOS)
        super().__init__(node, machine)
        # reliable, transient local (matches every reader), deeper than a batch
        rogue = QoSProfile(depth=2 * BATCH, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.rogue = {topic: node.create_publisher(kind, topic, rogue) for topic, kind in (
            (fc.JOINT_STATES, JointState), (fc.OFFSETS, JointState), (fc.SERVO_COMMANDS, JointState),
            (fc.REFERENCE, JointTrajectory), (fc.TRAJECTORY_REFERENCE, JointTrajectory), (fc.CLOCK, Clock),
            (fc.DIAGNOSTICS, DiagnosticArray))}
        self.rogue.update({fc.PATH: self.pub_path, fc.JOINT_GOAL: self.pub_goal, fc.FEED_OVERRIDE: self.pub_override,
                           fc.PROGRAM: node.create_publisher(String, fc.PROGRAM, ros_io.qos(contract.PROGRAM.qos))})

    def on_diagnostics(self, msg):
        for status in msg.status:
            if status.hardware_id == 'machine_ctrl':            # the graph's (rogue ones have others)
                values = {kv.key: kv.value for kv in status.values}
                self.diagnostics[status.name] = values
                self.history.setdefault(status.name, deque(maxlen=8)).append(
                    (round(time.monotonic(), 2), msg.header.stamp.sec, msg.header.stamp.nanosec,
                     {k: v for k, v in values.items() if k in fc.COUNTERS}))

    def on_truth(self, msg):
        self.truth = np.array(msg.position)

    def on_estimate(self, msg):
        self.progress.report(self.progress.clock.step(msg.header.stamp))

    def diag(self, node, key, default='0'):
        return self.diagnostics.get(node, {}).get(key, default)

    def counter(self, node: str, key: str) -> int:
        if node == 'trajectory':
            return int(self.status().get(key, '0'))
        return int(self.diag(node, key))

    def trim(self) -> None:
        """Keep the status history short over a long campaign (only the newest is read)."""
        del self.statuses[:-10]


# expected matched readers of each topic the test publishes on (README "Node graph")
READERS = {fc.JOINT_STATES: 4, fc.OFFSETS: 1, fc.SERVO_COMMANDS: 1, fc.REFERENCE: 4, fc.TRAJECTORY_REFERENCE: 1,
           fc.CLOCK: 1, fc.DIAGNOSTICS: 1, fc.PATH: 1, fc.JOINT_GOAL: 1, fc.FEED_OVERRIDE: 1, fc.PROGRAM: 1}


@pytest.fixture(scope='module')
def graph(micromill, ros_env, tmp_path_factory):
    with Supervisor(ros_env, log_dir=tmp_path_factory.mktemp('fuzz-logs'), stop_timeout=3.0) as supervisor:
        supervisor.start_nodes(graph_specs(micromill))
        yield supervisor


@pytest.fixture(scope='module')
def client(micromill, graph, ros_env):
    import rclpy
    with private_context(ros_env) as context:
        node = rclpy.create_node('fuzz_client', context=context)
        c = FuzzClient(node, micromill)
        try:
            c.wait(lambda: c.status().get('streamed_to_step', '') != '' and c.truth is not None
                   and all(n in c.diagnostics for n in NODES), 'the graph running', 120, graph.check)
            # the table settles on the compensated hold position first (a few um): start from there
            c.wait(lambda: int(c.diag('hw_sim', 'step')) > 3000, 'the machine settled', 120, graph.check)
            for topic, publisher in c.rogue.items():    # every reader matched: none misses a message
                c.wait(lambda: publisher.get_subscription_count() >= max(READERS[topic], node.count_subscribers(topic)),
                       f'the readers of {topic}', 60, graph.check)
            c.wait_listening(60, graph.check, c.command_publishers)   # no command before the match
            yield c
        finally:
            c.close()
            node.destroy_node()


def callback_errors(graph) -> dict[str, int]:
    """Lines of each node's log that tell of an exception a callback raised (caught by
    node_common.spin, so the node went on)."""
    out = {}
    for name in NODES:
        path = graph.log_dir / f'{name}.log'
        text = path.read_text(errors='replace') if path.exists() else ''
        out[name] = len(re.findall(r'callback failed|Traceback', text))
    return out


class Campaign:
    """The topic campaign's books: what was sent, the refusals each node counter must show
    (bounds since the start), the position the machine must keep."""

    def __init__(self, client, graph):
        self.client, self.graph = client, graph
        self.sent = Counter()                      # topic -> messages
        self.kinds = Counter()                     # (topic, kind) -> messages
        self.bounds: dict[tuple[str, str], list] = {}
        self.baseline = {}
        self.used_future: set[int] = set()
        self.examples = 0
        self.seconds = 0.0
        self.parameters = Counter()                # (node, kind, outcome) -> sets
        self.services = Counter()                  # (service, outcome) -> calls
        self.truth = client.truth.copy()
        self.rotary = np.array([a.unit == 'rad' for a in fc.MACHINE.axes])
        keys = [(node, fc.REJECTED) for node in fc.REFERENCE_READERS] + [
            ('compensation', 'rejected_chunks'), ('hw_sim', 'refused_commands'), ('hw_sim', 'stale_commands'),
            ('trajectory', 'rejected_goals')]
        for key in keys:
            self.baseline[key] = client.counter(*key)
            self.bounds[key] = [0, 0]
        # the servos answer a re-sent state again (hw_sim re-sends what it waits on): some
        # answers come after hw_sim moved on, counted stale, whatever the test sends
        self.bounds[('hw_sim', 'stale_commands')][1] = None

    def counted(self, key) -> int:
        return self.client.counter(*key) - self.baseline[key]

    def account(self, case) -> None:
        for key, (low, high) in fc.effects(case).items():
            bound = self.bounds[key]
            bound[0] += low
            bound[1] = None if high is None or bound[1] is None else bound[1] + high
        self.sent[case.topic] += 1
        self.kinds[(case.topic, case.kind)] += 1

    def message(self, case):
        msg = case.message()
        if case.topic == fc.JOINT_STATES and case.kind.startswith('future'):
            # a step node takes a skip ahead that comes twice in a row (hw_sim re-sends what it
            # waits on): every future state of the campaign has a stamp of its own
            step = fc.stamp_step(case.stamp)
            while step in self.used_future:
                step += 1
            self.used_future.add(step)
            msg.header.stamp.sec, msg.header.stamp.nanosec = fc.on_grid(step)
        return msg

    def run(self, batch) -> None:
        client, graph = self.client, self.graph
        started = time.monotonic()
        before = {key: client.counter(*key) for key in self.bounds}
        for case in batch:
            msg = self.message(case)
            self.account(case)
            if case.topic not in fc.GOAL_TOPICS:
                client.rogue[case.topic].publish(msg)
                if STEPWISE:
                    self.wait_counted(case)
                continue
            key = ('trajectory', 'rejected_goals')
            want = self.baseline[key] + self.bounds[key][0]
            client.rogue[case.topic].publish(msg)
            client.wait(lambda: client.counter(*key) >= want, f'the refusal of {case}', check=graph.check)
            status = client.status()
            assert int(status['rejected_goals']) == want, (case, status)
            what = fc.GOAL_TOPICS[case.topic] + ': '
            assert status['last_rejection'].startswith(what) and status['last_rejection'][len(what):].strip(), \
                (case, status['last_rejection'])
        self.wait_counted()
        for key, (low, high) in self.bounds.items():
            assert high is None or self.counted(key) <= high, (key, self.counted(key), (low, high), batch)
            prefixes = fc.REASON_PREFIXES.get(key)
            if prefixes and client.counter(*key) > before[key]:
                node = key[0]
                reason = client.diag(node, fc.REASON_KEYS.get(node, 'last_rejection'), '')
                assert reason and any(reason.startswith(p) and reason[len(p):].strip() for p in prefixes), \
                    (key, reason)
        self.assert_still()
        client.trim()
        self.examples += 1
        self.seconds += time.monotonic() - started

    def wait_counted(self, case=None) -> None:
        """Until every counter has counted the refusals it must."""
        try:
            self.client.wait(lambda: all(self.counted(key) >= low for key, (low, _) in self.bounds.items()),
                             'every refusal counted on /diagnostics', timeout=30 if case else 120, check=self.graph.check)
        except Timeout:
            short = {f'{n}.{c}': (self.counted((n, c)), bound) for (n, c), bound in self.bounds.items()
                     if self.counted((n, c)) < bound[0]}
            history = {n: list(self.client.history.get(n, ())) for n in {n for n, _ in self.bounds}}
            raise AssertionError(f'refusals not counted (counted, [least, most]): {short}'
                                 + (f' after {case}' if case else '') + f'; /diagnostics lately: {history}') from None

    def assert_still(self, reference=True) -> None:
        """Every node running, hw_sim not faulted, the trajectory node idle, nothing moved."""
        client, graph = self.client, self.graph
        graph.check()
        assert set(graph.alive()) == set(NODES)
        assert client.diag('hw_sim', 'fault', '') == '', client.diagnostics['hw_sim']
        assert client.status()['state'] == 'idle', client.status()
        if reference:
            assert client.reference.changed is None, f'the reference moved: (step, row, first row) {client.reference.changed}'
        moved = np.abs(client.truth - self.truth)
        assert moved[~self.rotary].max() < LINEAR_STILL and moved[self.rotary].max() < ROTARY_STILL, moved

    def report(self) -> dict:
        refusals = {f'{node}.{counter}': self.counted((node, counter)) for node, counter in sorted(self.bounds)}
        return {
            'messages': sum(self.sent.values()), 'examples': self.examples, 'batch': BATCH,
            'seconds': round(self.seconds, 1), 'per_topic': dict(sorted(self.sent.items())),
            'per_kind': {f'{t} {k}': n for (t, k), n in sorted(self.kinds.items())},
            'refusals': refusals,
            'parameter_sets': {f'{n} {k} {o}': c for (n, k, o), c in sorted(self.parameters.items())},
            'service_calls': {f'{s} {o}': c for (s, o), c in sorted(self.services.items())},
            'alive': sorted(self.graph.alive()), 'crashes': len(NODES) - len(self.graph.alive()),
            'callback_errors_logged': callback_errors(self.graph), 'logs': str(self.graph.log_dir),
        }


@pytest.fixture(scope='module')
def campaign(client, graph):
    books = Campaign(client, graph)
    yield books
    report = books.report()
    print('\nfuzz campaign:', json.dumps(report, indent=1))
    if REPORT:
        with open(REPORT, 'w') as f:
            json.dump(report, f, indent=1)


# -- 0. the oracle against the nodes' own validation, without a graph ---------------------------
@fuzz_settings(max(300, MESSAGES // 10))
@given(case=st.one_of(fc.joint_goals(), fc.paths(), fc.chunks(fc.REFERENCE), fc.chunks(fc.TRAJECTORY_REFERENCE),
                      fc.joint_states(), fc.offsets()))
def test_every_generated_case_is_one_the_nodes_validation_refuses(case):
    """What the strategies call invalid, the parsers the nodes run refuse (a path beyond
    the workspace is the planner's to refuse: on the graph below)."""
    from rclpy.serialization import serialize_message

    from machine_ctrl.recording.cdr import ChunkDecoder
    from trajectory import moves
    clock = ros_io.StepClock.of(fc.MACHINE)
    if case.topic == fc.JOINT_GOAL:
        times = [0.0] * len(case.points) if case.times is None else [contract.seconds(*t) for t in case.times]
        with pytest.raises(ValueError):
            moves.through_waypoints(fc.MACHINE, [0.0] * len(fc.AXES), list(case.names), [list(p) for p in case.points],
                                    times)
    elif case.topic == fc.PATH:
        if 'unreachable' not in case.kind:
            with pytest.raises(ValueError):
                ros_io.path_to_cl(case.message(), fc.WORKPIECE)
    elif case.topic in (fc.REFERENCE, fc.TRAJECTORY_REFERENCE):
        data = serialize_message(case.message())
        for wanted in fc.REFERENCE_READERS.values() if case.topic == fc.REFERENCE else (fc.AXES,):
            with pytest.raises(ros_io.InvalidMessage):
                ros_io.parse_chunk_bytes(clock, ChunkDecoder(), data, wanted)
    elif fc.stamp_step(case.stamp) is not None:       # on grid: the content is refused
        wanted = fc.AXES if case.topic == fc.JOINT_STATES else fc.OFFSET_AXES
        with pytest.raises(ros_io.InvalidMessage):
            ros_io.select(case.message(), 'position', wanted)


# -- 1. topics: only invalid messages, nothing moves --------------------------------------------
@fuzz_settings(TOPIC_EXAMPLES)
@given(batch=fc.batches(BATCH))
def test_invalid_messages_on_every_topic_are_refused_with_a_reason_and_move_nothing(campaign, batch):
    campaign.run(batch)


def test_the_campaign_reached_every_topic_and_every_counter(campaign):
    assert campaign.examples == TOPIC_EXAMPLES
    assert set(campaign.sent) == set(READERS), campaign.sent
    assert sum(campaign.sent.values()) >= MESSAGES
    for key, (low, _) in campaign.bounds.items():
        assert campaign.counted(key) >= low, (key, campaign.counted(key))
    for node in list(fc.REFERENCE_READERS) + ['compensation', 'trajectory']:
        assert any(campaign.counted(key) > 0 for key in campaign.bounds if key[0] == node), node


# -- 2. parameters -------------------------------------------------------------------------------
class Parameters:
    """rcl_interfaces parameter services of every node (what `ros2 param` calls)."""

    def __init__(self, client):
        from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
        from rcl_interfaces.srv import SetParametersAtomically
        self.client, node = client, client.node
        self.kinds = {'list': ListParameters, 'describe': DescribeParameters, 'get': GetParameters,
                      'set': SetParameters, 'atomic': SetParametersAtomically}
        suffix = {'list': 'list_parameters', 'describe': 'describe_parameters', 'get': 'get_parameters',
                  'set': 'set_parameters', 'atomic': 'set_parameters_atomically'}
        self.services = {(n, k): node.create_client(kind, f'/{n}/{suffix[k]}') for n in NODES
                         for k, kind in self.kinds.items()}
        self.declared = {n: self.discover(n) for n in NODES}

    def call(self, node, kind, request, timeout=30.0):
        service = self.services[(node, kind)]
        assert service.wait_for_service(timeout_sec=timeout), f'/{node} {kind} parameters service'
        future = service.call_async(request)
        self.client.wait(future.done, f'the answer of /{node} {kind}', timeout)
        return future.result()

    def discover(self, node) -> dict[str, fc.Declared]:
        names = list(self.call(node, 'list', self.kinds['list'].Request()).result.names)
        descriptors = self.call(node, 'describe', self.kinds['describe'].Request(names=names)).descriptors
        values = self.get(node, names)
        return {d.name: fc.Declared.of(d, values[d.name]) for d in descriptors}

    def get(self, node, names) -> dict:
        from rclpy.parameter import parameter_value_to_python
        answer = self.call(node, 'get', self.kinds['get'].Request(names=list(names)))
        return {n: fc.plain(parameter_value_to_python(v)) for n, v in zip(names, answer.values)}


@pytest.fixture(scope='module')
def parameters(client):
    return Parameters(client)


@st.composite
def parameter_requests(draw, declared):
    node = draw(st.sampled_from(NODES))
    sim_time = declared[node].get('use_sim_time') is not None and declared[node]['use_sim_time'].value is True
    cases = draw(st.lists(fc.parameter_case(node, declared[node], sim_time), min_size=1, max_size=3,
                          unique_by=lambda c: c.name))
    return node, cases, draw(st.booleans())


@fuzz_settings(PARAMETER_EXAMPLES)
@given(data=st.data())
def test_parameter_sets_are_refused_with_the_reason_or_taken_and_read_back(campaign, parameters, data):
    node, cases, atomically = data.draw(parameter_requests(parameters.declared))
    declared = parameters.declared[node]
    known = [c.name for c in cases if c.name in declared]
    before = parameters.get(node, known)
    request = [c.message() for c in cases]
    if atomically:
        result = parameters.call(node, 'atomic', parameters.kinds['atomic'].Request(parameters=request)).result
        results = [result] * len(cases)
        expect_all = 'accepted' if all(c.expect == 'accepted' for c in cases) else 'refused'
        expects = [expect_all] * len(cases)
    else:
        results = parameters.call(node, 'set', parameters.kinds['set'].Request(parameters=request)).results
        expects = [c.expect for c in cases]
    after = parameters.get(node, known)
    assert len(results) == len(cases), (node, len(results), len(cases))
    for case, result, expect in zip(cases, results, expects):
        outcome = fc.check_parameter_answer(node, case, result, expect, declared, before, after)
        campaign.parameters[(node, case.kind, outcome)] += 1
    restore = [fc.ParameterCase(node, 'restore', n, declared[n].type, before[n], 'accepted').message()
               for c, r in zip(cases, results) if r.successful and c.kind == 'valid' for n in [c.name]]
    if restore:
        answer = parameters.call(node, 'set', parameters.kinds['set'].Request(parameters=restore))
        assert all(r.successful for r in answer.results), answer
    campaign.client.trim()
    campaign.assert_still()


def test_a_parameter_of_a_type_outside_the_enum_is_refused_with_the_reason(campaign, parameters):
    """rcl_interfaces ParameterType is a uint8: 10..255 are no type. rclpy's parameter service
    raises on one (Parameter.from_parameter_msg) and answers nothing; node_parameters refuses it
    with the reason: set_parameters that one alone (the request's others are set),
    set_parameters_atomically the whole request (nothing set)."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    bad = Parameter(name='feed', value=ParameterValue(type=200))
    reason = "parameter 'feed': type 200 is not a ParameterType (0-9)"
    for node in NODES:
        sim_time = parameters.get(node, ['use_sim_time'])['use_sim_time']        # set again as it is
        good = Parameter(name='use_sim_time', value=ParameterValue(type=ParameterType.PARAMETER_BOOL,
                                                                   bool_value=sim_time))
        one, other = parameters.call(node, 'set', parameters.kinds['set'].Request(parameters=[bad, good])).results
        assert (one.successful, one.reason) == (False, reason), (node, one)
        assert other.successful, (node, other)
        whole = parameters.call(node, 'atomic', parameters.kinds['atomic'].Request(parameters=[good, bad])).result
        assert (whole.successful, whole.reason) == (False, reason), (node, whole)
        assert parameters.get(node, ['use_sim_time'])['use_sim_time'] is sim_time
    campaign.assert_still()


@pytest.mark.parametrize('atomically', [False, True])
def test_an_empty_parameter_name_is_refused(campaign, parameters, atomically):
    """rclpy 7.1's undeclared-name check tests any() of the names, and '' is falsy: without
    node_parameters' own check, a parameter named '' would be created on any node."""
    case = fc.ParameterCase('trajectory', 'unknown', '', fc.BOOL, True, 'refused')
    if atomically:
        result = parameters.call('trajectory', 'atomic',
                                 parameters.kinds['atomic'].Request(parameters=[case.message()])).result
    else:
        (result,) = parameters.call('trajectory', 'set', parameters.kinds['set'].Request(parameters=[case.message()])).results
    assert not result.successful and result.reason.strip(), result


# -- 3. services in any order ----------------------------------------------------------------------
@fuzz_settings(SERVICE_EXAMPLES)
@given(calls=st.lists(fc.service_call, min_size=1, max_size=8))
def test_services_in_any_order_answer_with_a_reason_and_fault_nothing(campaign, graph, calls):
    client = campaign.client
    for call in calls:
        if call[0] == 'trigger':
            service = call[1]
            success, message = client.call(service)
        elif call[0] == 'switch':
            service = call[1]
            success, message = client.call(service, call[2])
            assert success, (call, message)               # always accepted (README)
        else:
            service = contract.CANCEL.name
            goal = {'zero': None, 'active': client.status().get('goal_id') or None}.get(call[1], call[1])
            code, canceling = _cancel(client, goal, call[2])
            assert code in (0, 1, 2, 3), (call, code)
            # an error code cancels nothing; ERROR_NONE with none canceling is the session's
            # "nothing to cancel" (test_trajectory_session), although action_msgs/CancelGoal
            # says ERROR_NONE means the list is not empty
            assert code == 0 or not canceling, (call, code, canceling)
            success, message = code == 0, f'code {code}'
        campaign.services[(service, 'success' if success else 'refused')] += 1
        assert success or message.strip(), call          # a refusal says why
        graph.check()
        assert client.diag('hw_sim', 'fault', '') == '', (call, client.diagnostics['hw_sim'])
    client.trim()
    assert set(graph.alive()) == set(NODES)


def _cancel(client, goal_id, stamp):
    from action_msgs.srv import CancelGoal
    service = client._services.get(contract.CANCEL.name) or client._services.setdefault(
        contract.CANCEL.name, client.node.create_client(CancelGoal, contract.CANCEL.name))
    assert service.wait_for_service(timeout_sec=30)
    request = CancelGoal.Request()
    if goal_id is not None:
        request.goal_info.goal_id.uuid = list(uuid.UUID(goal_id).bytes)
    request.goal_info.stamp.sec, request.goal_info.stamp.nanosec = stamp
    future = service.call_async(request)
    client.wait(future.done, 'the answer of trajectory/cancel', 30)
    answer = future.result()
    return answer.return_code, list(answer.goals_canceling)


def test_after_the_services_the_machine_comes_to_rest_idle(campaign, graph):
    client = campaign.client
    assert client.call(contract.DUAL_STAGE_ENABLE.name, True)[0]
    assert client.call(contract.COMPENSATION_ENABLE.name, True)[0]
    client.call(contract.STOP.name)
    client.wait(lambda: client.status()['state'] == 'idle', 'idle after a stop', check=graph.check)
    client.call(contract.HOME.name)
    client.wait(lambda: client.status()['state'] == 'idle', 'idle at home', check=graph.check)
    graph.check()
    assert client.diag('hw_sim', 'fault', '') == ''


# -- 4. trusted by design: the documented outcome ---------------------------------------------------
def _rogue_hw_sim_fault(fault: str, step: str):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    return DiagnosticArray(status=[DiagnosticStatus(level=bytes([fc.ERROR]), name='hw_sim', message=fault,
                                                    hardware_id='rogue',
                                                    values=[KeyValue(key='fault', value=fault),
                                                            KeyValue(key='step', value=step)])])


# Unicode digits that are not decimal ('²'.isdigit() but int('²') fails) have their own test
ascii_step = st.one_of(st.just(''), st.text('0123456789', min_size=1, max_size=40), st.text(max_size=8).filter(
    lambda s: not s.isdigit() or s.isascii()))


@fuzz_settings(max(3, SERVICE_EXAMPLES // 3))
@given(fault=fc.text, offset=st.integers(-5000, 5000), step_text=ascii_step, relative=st.booleans())
def test_a_rogue_hw_sim_fault_status_is_trusted_as_documented(campaign, graph, fault, offset, step_text, relative):
    """README: /diagnostics is how the trajectory node learns hw_sim's faults, and a
    well-formed message is trusted, whoever sends it: an ERROR status named hw_sim faults
    the trajectory node (goals refused, the stream held), and hw_sim's next status (1 Hz,
    not faulted) brings it back to idle. Nothing crashes, whatever the step text."""
    client = campaign.client
    if relative:
        step_text = str(max(int(client.diag('hw_sim', 'step')) + offset, 0))
    n = len(client.statuses)
    client.rogue[fc.DIAGNOSTICS].publish(_rogue_hw_sim_fault(fault, step_text))
    client.wait_states(n, ['fault', 'idle'], check=graph.check)
    assert any(s.message == 'fault' and {kv.key: kv.value for kv in s.values}.get('fault') == fault
               for s in client.statuses[n:]), fault
    assert client.diag('hw_sim', 'fault', '') == ''
    graph.check()
    client.trim()


# -- 5. defects the fuzzing found, fixed (each was a strict xfail until then) -------------------------
def test_an_off_grid_servo_command_is_counted_on_diagnostics(campaign, graph):
    client = campaign.client
    key = ('hw_sim', 'refused_commands')
    before = client.counter(*key)
    off_grid = fc.StateCase(fc.SERVO_COMMANDS, 'off_grid', (5, 12_345), '', ('x_c',), (), (), (0.0,))
    # then a command far ahead, which is counted: delivered after the first (one writer, reliable)
    sentinel = fc.StateCase(fc.SERVO_COMMANDS, 'future', fc.on_grid(10**10), '', ('x_c',), (), (), (0.0,))
    client.rogue[fc.SERVO_COMMANDS].publish(off_grid.message())
    client.rogue[fc.SERVO_COMMANDS].publish(sentinel.message())
    # both counted (a diagnostics timer may publish between the two: wait for both)
    client.wait(lambda: client.counter(*key) >= before + 2, 'both refused', check=graph.check)
    assert client.counter(*key) == before + 2, client.diagnostics['hw_sim']


def test_finite_commands_beyond_the_float_range_for_a_step_ahead_are_refused(campaign, graph):
    client = campaign.client
    key = ('hw_sim', 'refused_commands')
    before = client.counter(*key)
    huge = fc.StateCase(fc.SERVO_COMMANDS, 'future', fc.on_grid(10**10 + 3), '', ('x_c', 'y_c'), (), (), (1e308, 1e308))
    sentinel = fc.StateCase(fc.SERVO_COMMANDS, 'future', fc.on_grid(10**10 + 5), '', ('x_c',), (), (), (0.0,))
    try:
        client.rogue[fc.SERVO_COMMANDS].publish(huge.message())
        client.rogue[fc.SERVO_COMMANDS].publish(sentinel.message())
        client.wait(lambda: client.counter(*key) >= before + 2 or client.diag('hw_sim', 'fault', ''),
                    'both refused', check=graph.check)
        assert client.diag('hw_sim', 'fault', '') == '' and client.counter(*key) == before + 2, \
            client.diagnostics['hw_sim']
    finally:                            # today the machine faults: reset it for the tests after
        if client.diag('hw_sim', 'fault', '') or client.status().get('state') == 'fault':
            assert client.call(contract.RESET.name)[0]
            client.wait(lambda: client.diag('hw_sim', 'fault', '') == '' and client.status()['state'] == 'idle',
                        'hw_sim reset', check=graph.check)


def test_a_fault_step_in_unicode_digits_faults_the_trajectory_node(campaign, graph):
    client = campaign.client
    n = len(client.statuses)
    client.rogue[fc.DIAGNOSTICS].publish(_rogue_hw_sim_fault('fault with step ²', '²'))
    # then a fault status the node takes (delivered after the first: one writer, reliable);
    # once faulted, the node keeps the first fault
    client.rogue[fc.DIAGNOSTICS].publish(_rogue_hw_sim_fault('sentinel fault', ''))
    client.wait_states(n, ['fault', 'idle'], check=graph.check)
    faults = [{kv.key: kv.value for kv in s.values}['fault'] for s in client.statuses[n:] if s.message == 'fault']
    assert faults[0] == 'fault with step ²', faults


def test_a_well_formed_future_state_is_refused_by_contour_error(campaign, graph):
    """Last of the module. hw_sim stays held to contour_error's pace (the test reports its
    estimates), so contour_error's keep-last queue never drops the test's two states behind
    a busy core: a loaded run that released hw_sim first lost them, uncounted. Should
    contour_error take the future state and estimate nothing more, hw_sim holds and the wait
    times out: the failure this test is for."""
    client = campaign.client
    key = ('contour_error', fc.REJECTED)
    before = client.counter(*key)
    well_formed = fc.StateCase(fc.JOINT_STATES, 'future', fc.on_grid(2 * 10**10 + 7), '', fc.AXES,
                               (0.0,) * len(fc.AXES), (0.0,) * len(fc.AXES), ())
    sentinel = fc.StateCase(fc.JOINT_STATES, 'off_grid', (9, 12_345), '', fc.AXES, (0.0,) * len(fc.AXES), (), ())
    client.rogue[fc.JOINT_STATES].publish(well_formed.message())
    client.rogue[fc.JOINT_STATES].publish(sentinel.message())
    # the future state is refused once a real state that is not its successor comes
    client.wait(lambda: client.counter(*key) >= before + 2, 'both refused', check=graph.check)
    assert client.counter(*key) == before + 2, client.diagnostics['contour_error']
