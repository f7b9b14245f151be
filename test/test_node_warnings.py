"""A node's RuntimeWarnings reach its log every time (node_common.log_runtime_warnings): rclpy
says so when a service's answer is lost (run115: `ros2 service call` waited 90 s for an answer
the node had computed; Python had printed such a warning at most once, on stderr)."""
import warnings

from machine_ctrl.ros.node_common import log_runtime_warnings


def send_response():
    warnings.warn('failed to send response (timeout): client will not receive response', RuntimeWarning)


def test_every_runtime_warning_is_an_error_in_the_log_other_warnings_are_left_alone(ros_node, capfd):
    """On a real node's logger (its lines on stderr, read back)."""
    logger = ros_node('warnings_test').get_logger()
    with warnings.catch_warnings(record=True) as others:       # restores the filters and showwarning after
        warnings.simplefilter('default')
        log_runtime_warnings(logger)
        send_response()
        send_response()                                         # the same line again: logged again
        warnings.warn('an old API', DeprecationWarning)
    errors = [line for line in capfd.readouterr().err.splitlines() if '[ERROR]' in line and '[warnings_test]' in line]
    assert len(errors) == 2, errors
    assert 'RuntimeWarning: failed to send response (timeout): client will not receive' in errors[0]
    assert [str(w.message) for w in others] == ['an old API']
