"""The ROS isolation fixtures (test/ros_fixtures.py): own domain, localhost discovery, the
same domain for in-process nodes and child processes, and cleanup."""
import fcntl
import os
import sys
import tempfile
import textwrap

import pytest

# A child node: echoes /ping to /pong, says 'ready' once both endpoints have matched.
ECHO = textwrap.dedent('''
    import time
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from std_msgs.msg import String
    rclpy.init()
    node = rclpy.create_node('echo')
    pub = node.create_publisher(String, '/pong', 10)
    sub = node.create_subscription(String, '/ping', pub.publish, 10)
    while not (pub.get_subscription_count() and sub.get_publisher_count()):
        time.sleep(0.01)
    print('ready', node.get_namespace(), node.context.get_domain_id(), flush=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
''')


def test_the_session_holds_a_domain_of_its_own_with_localhost_discovery(ros_env):
    domain_id = int(ros_env['ROS_DOMAIN_ID'])
    assert 1 <= domain_id <= 101
    assert os.environ['ROS_DOMAIN_ID'] == str(domain_id)
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == ros_env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert 'ROS_LOCALHOST_ONLY' not in os.environ
    assert os.environ['AMENT_PREFIX_PATH']
    lock = os.path.join(tempfile.gettempdir(), f'ros_domain_id.{domain_id}.lock')
    fd = os.open(lock, os.O_RDWR)
    try:
        with pytest.raises(BlockingIOError):        # another session could not take it
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    finally:
        os.close(fd)


def test_rclpy_context_is_initialised_in_the_session_domain(rclpy_context, ros_env):
    assert rclpy_context.ok()
    assert rclpy_context.get_domain_id() == int(ros_env['ROS_DOMAIN_ID'])


def test_a_child_process_and_this_process_talk_in_the_session_domain(ros_supervisor, ros_node, rclpy_context,
                                                                     ros_env):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.task import Future
    from std_msgs.msg import String

    ros_supervisor.start('echo', [sys.executable, '-c', ECHO])
    node = ros_node('pinger')
    answer = Future()
    pub = node.create_publisher(String, '/ping', 10)
    node.create_subscription(String, '/pong', lambda msg: answer.set_result(msg.data), 10)
    ready = ros_supervisor.wait_for_line('echo', 'ready', timeout=30)
    assert ready.split()[-1] == ros_env['ROS_DOMAIN_ID']
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    try:
        # This side's endpoints may match a moment after the child's did.
        while not (pub.get_subscription_count() and node.count_publishers('/pong')):
            executor.spin_once(timeout_sec=0.01)
        pub.publish(String(data='hello'))
        executor.spin_until_future_complete(answer, timeout_sec=10)
    finally:
        executor.shutdown()
    assert answer.done() and answer.result() == 'hello'
    ros_supervisor.check()
