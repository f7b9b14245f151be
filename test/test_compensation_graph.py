"""compensation_node over real DDS: reference_node (remapped to /trajectory/reference) ->
compensation_node -> /reference, against the same core offline; a malformed chunk, refused
with its reason on /diagnostics and changing nothing; the runtime switch /compensation/enable."""
import time

import numpy as np

from compensation.compensate import Compensator
from compensation.error_map import load_error_map
from compensation.stream import CompensationStream
from machine_ctrl import contract, parameters
from machine_ctrl.ros.graph import NodeSpec
from trajectory.contours import contour_reference

CHUNK = parameters.REFERENCE.spec('chunk_steps').default            # the reference node's rows per chunk
LOOKAHEAD = parameters.REFERENCE.spec('lookahead_steps').default    # and how far it streams ahead


def _spin_until(executor, condition, timeout, supervisor, action=None):
    """Spin until condition(); `action` (if any) is repeated every 0.5 s meanwhile."""
    deadline = time.monotonic() + timeout
    last = 0.0
    while not condition():
        assert time.monotonic() < deadline, 'timed out'
        supervisor.check()
        if action is not None and time.monotonic() - last > 0.5:
            action()
            last = time.monotonic()
        executor.spin_once(timeout_sec=0.05)


def test_compensation_node_in_the_graph(micromill, ros_node, ros_supervisor):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from std_srvs.srv import SetBool
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from machine_ctrl.ros import messages as ros_io

    model = str(micromill.simulation.error_map_path(micromill.yaml_path))
    common = {'machine': str(micromill.yaml_path)}
    reference = NodeSpec('reference', 'machine_ctrl.ros.reference_node', 'ReferenceNode', {**common, 'contour': 'circle'})
    compensation = NodeSpec('compensation', 'machine_ctrl.ros.compensation_node', 'CompensationNode', {**common, 'model': model})
    node = ros_node('probe')
    chunks, firsts, status = {}, [], {}

    def on_chunk(msg):
        first, p, v, a = ros_io.parse_chunk(ros_io.StepClock(micromill.control_period), msg, micromill.axis_names)
        chunks[first] = (np.array(p), np.array(v), np.array(a))
        firsts.append(first)                  # every chunk out, in order: a forwarded bad one shows

    node.create_subscription(JointTrajectory, contract.REFERENCE.name, on_chunk, ros_io.REFERENCE_QOS)
    node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, lambda msg: status.update(
        {kv.key: kv.value for s in msg.status if s.name == 'compensation' for kv in s.values}),
        ros_io.qos(contract.DIAGNOSTICS_READER_QOS))
    bad = node.create_publisher(JointTrajectory, '/trajectory/reference', ros_io.REFERENCE_QOS)
    clock = node.create_publisher(Clock, '/clock', 10)
    enable = node.create_client(SetBool, '/compensation/enable')
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        ros_supervisor.start('compensation', compensation.argv())
        _spin_until(executor, lambda: enable.service_is_ready(), 30, ros_supervisor)
        msg = JointTrajectory(joint_names=list(micromill.axis_names))
        msg.points = [JointTrajectoryPoint(positions=[float('nan')] * 9)]
        bad.publish(msg)                                          # refused, the node keeps running
        ros_supervisor.start('reference', reference.argv() + ['-r', '/reference:=/trajectory/reference'])
        _spin_until(executor, lambda: len(chunks) >= LOOKAHEAD // CHUNK, 60, ros_supervisor)
        # the reference node streams its lookahead until /clock moves: the node's status once it
        # has taken all of those chunks and refused the bad one
        _spin_until(executor, lambda: status.get('chunks') == str(LOOKAHEAD // CHUNK)
                    and status.get('rejected_chunks') == '1', 60, ros_supervisor)
        assert status['last_rejection'] == 'reference chunk: point 0 positions holds NaN or inf', status
        assert firsts == list(range(0, LOOKAHEAD, CHUNK))            # nothing was forwarded for it

        ref = contour_reference(micromill, 'circle')
        stream = CompensationStream(Compensator.from_map(micromill, load_error_map(model, micromill.axis_names)),
                                    micromill.control_period)
        for first in range(0, LOOKAHEAD, CHUNK):
            rows = [ref.row(k) for k in range(first, first + CHUNK)]
            want = stream.transform(first, *(np.array(x) for x in zip(*rows)))
            for got, expected in zip(chunks[first], want[:3]):
                assert (got == expected).all(), first                 # bit-identical to the core
            assert np.abs(chunks[first][0][:, 3:] - np.array([r[0] for r in rows])[:, 3:]).max() > 1e-7
        # and its state is the core's that never saw the bad chunk (str(): as the status prints them)
        assert (status['capped_rows'], status['max_predicted_residual_m']) == (
            str(stream.capped_rows), str(stream.max_residual))

        future = enable.call_async(SetBool.Request(data=False))
        _spin_until(executor, future.done, 10, ros_supervisor)
        assert future.result().success
        tick = Clock(clock=ros_io.StepClock(micromill.control_period).stamp(LOOKAHEAD))
        last = 2 * LOOKAHEAD - CHUNK                               # the lookahead from the tick on
        _spin_until(executor, lambda: last in chunks, 60, ros_supervisor, lambda: clock.publish(tick))
        for first in range(LOOKAHEAD + 1500, last + 1, CHUNK):     # after the 1000-step ramp: the input
            rows = [ref.row(k) for k in range(first, first + CHUNK)]
            assert (chunks[first][0] == np.array([r[0] for r in rows])).all()
        assert ros_supervisor['compensation'].running()
    finally:
        executor.shutdown()
