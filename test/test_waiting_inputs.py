"""What a step node waits for, on /diagnostics (`waiting_for`), with the writers its reader
is matched with: real nodes over real DDS, each in its own process (hw_sim, dual_stage,
servo_fine; no node streams a reference), in a namespace of their own."""
import pytest

from machine_ctrl.app.processes import Supervisor
from machine_ctrl.ros.graph import default_graph
from ros_fixtures import private_context
from test_faults import GUARD, Client

NAMESPACE = '/waiting'
NODES = ('hw_sim', 'dual_stage', 'servo_fine')


@pytest.fixture(scope='module')
def graph(micromill, ros_env, tmp_path_factory):
    specs = [s for s in default_graph(micromill, contour=None, namespace=NAMESPACE) if s.name in NODES]
    assert sorted(s.name for s in specs) == sorted(NODES)
    with Supervisor(ros_env, log_dir=tmp_path_factory.mktemp('logs'), stop_timeout=3.0) as supervisor:
        supervisor.start_nodes(specs)
        yield supervisor


def test_step_nodes_say_which_input_they_wait_for_and_how_many_writers_it_has(micromill, graph, ros_env):
    import rclpy
    with private_context(ros_env) as context:
        node = rclpy.create_node('waiting_client', namespace=NAMESPACE, context=context)
        client = Client(node, micromill)
        try:
            # no reference writer at all; dual_stage is there but sends no offsets without one
            expected = {'dual_stage': 'reference (never received; 0 writers matched)',
                        'servo_fine': 'reference (never received; 0 writers matched), '
                                      'dual_stage/offsets (never received; 1 writer matched)'}
            client.wait(lambda: all(client.diag(n, 'waiting_for') == text for n, text in expected.items())
                        and client.diag('hw_sim', 'step') != '',           # each node's own 1 Hz report
                        f'the step nodes saying {expected}, and hw_sim its step', GUARD, graph.check)
            assert client.diag('hw_sim', 'step') == '0'          # lock-step: held at the first state, unanswered
        finally:
            client.close()
            node.destroy_node()
