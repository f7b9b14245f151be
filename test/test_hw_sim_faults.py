"""hw_sim faults over real DDS: a NaN command, a stroke violation and a missing command
each stop the machine and are reported on /diagnostics; hw_sim keeps running and /hw_sim/reset
recovers. The test node plays the servos."""
from machine_ctrl import contract
import math
import sys
import threading
import time

import pytest


class Commander:
    """Plays the servos: answers every /joint_states step with `policy(step, state)` ->
    efforts or None. The default policy is the machine's real servo laws holding the
    position of step 0 (open-loop zeros would let the table's force noise walk b_f out of
    its +-8.7 mrad stroke)."""

    def __init__(self, node, axes, machine):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import JointState
        from std_srvs.srv import Trigger

        from machine_ctrl.ros import messages as ros_io
        from machine_ctrl.control.servo import ServoGroup
        self.ros_io, self.node, self.axes = ros_io, node, axes
        self.servo = ServoGroup(machine, axes)
        self.hold = None
        self.policy = self.servo_policy
        self.steps, self.hw_diag = [], None
        self.pub = node.create_publisher(JointState, contract.SERVO_COMMANDS.name, ros_io.STEP_QOS)
        node.create_subscription(JointState, contract.JOINT_STATES.name, self.on_state, ros_io.STEP_QOS)
        node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self.on_diag, 50)
        self.reset_client = node.create_client(Trigger, '/hw_sim/reset')
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)
        self.running = True
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.thread.start()

    def servo_policy(self, step, state):
        position, velocity = state.position.tolist(), state.velocity.tolist()
        if self.hold is None:
            self.hold = position
        zeros = [0.0] * len(self.axes)
        return self.servo.step(self.hold, zeros, zeros, position, velocity)

    def spin(self):
        while self.running:
            self.executor.spin_once(timeout_sec=0.05)

    def on_state(self, msg):
        step = (msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec) // 100_000
        self.steps.append(step)
        efforts = self.policy(step, msg)
        if efforts is not None:
            self.pub.publish(self.ros_io.joint_state(msg.header.stamp, self.axes, effort=efforts))

    def on_diag(self, msg):
        for status in msg.status:
            if status.name == 'hw_sim':
                self.hw_diag = (status.level, status.message, {kv.key: kv.value for kv in status.values})

    def wait(self, condition, timeout=30.0, what=''):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return
            time.sleep(0.05)
        raise AssertionError(f'timed out waiting for {what}; last hw_sim diagnostics: {self.hw_diag}')

    def fault(self):
        return self.hw_diag is not None and self.hw_diag[1].startswith('FAULT')

    def reset(self):
        from std_srvs.srv import Trigger
        assert self.reset_client.wait_for_service(timeout_sec=10)
        future = self.reset_client.call_async(Trigger.Request())
        self.wait(future.done, what='reset response')
        return future.result()

    def stop(self):
        self.running = False
        self.thread.join(timeout=2)
        self.executor.shutdown()


def _commanded_hw_sim(micromill, ros_node, ros_supervisor, *parameters):
    """hw_sim with a short command timeout (and `parameters`, 'name:=value') and a Commander
    playing the servos; afterwards hw_sim must still be alive."""
    args = [a for p in ('command_timeout:=0.5', 'republish_period:=0.1', *parameters) for a in ('-p', p)]
    ros_supervisor.start('hw_sim', [sys.executable, '-m', 'machine_ctrl.ros.hw_sim_node', '--ros-args', *args])
    ros_supervisor.wait_for_line('hw_sim', 'ready', 60)
    c = Commander(ros_node('servos'), list(micromill.axis_names), micromill)
    yield c
    c.stop()
    assert ros_supervisor.alive() == ['hw_sim'], 'hw_sim died'


@pytest.fixture
def commander(micromill, ros_node, ros_supervisor):
    yield from _commanded_hw_sim(micromill, ros_node, ros_supervisor)


def test_nan_command_stops_the_machine_and_reset_recovers(commander):
    sent = []

    def policy(step, state):
        if step == 20 and not sent:
            sent.append(step)
            return [math.nan] + [0.0] * 8
        return commander.servo_policy(step, state)
    commander.policy = policy
    commander.wait(commander.fault, what='fault')
    assert 'non-finite command for x_c' in commander.hw_diag[1]
    # stopped: hw_sim reports every command of step 20 in hand (the finite answers to its
    # re-sends) and still step 20; then a few more re-sends of step 20, nothing after it
    commander.wait(lambda: commander.hw_diag[2]['waiting_for'] == '', what='the answers to step 20 in hand')
    assert commander.hw_diag[2]['step'] == '20' and commander.fault(), commander.hw_diag
    resent = commander.steps.count(20)
    commander.wait(lambda: commander.steps.count(20) >= resent + 3, what='step 20 re-sent')
    assert max(commander.steps) == 20
    response = commander.reset()
    assert response.success and 'non-finite' in response.message
    commander.wait(lambda: max(commander.steps) > 40, what='running again after reset')


def test_stroke_violation_stops_the_machine(commander):
    def policy(step, state):
        commands = commander.servo_policy(step, state)
        commands[3] = 40.0                                                 # push x_f open loop
        return commands
    commander.policy = policy
    commander.wait(commander.fault, what='fault')
    assert 'stroke violation on x_f' in commander.hw_diag[1]
    assert commander.hw_diag[0] == b'\x02'                                 # DiagnosticStatus.ERROR


def test_missing_command_times_out_into_a_fault(commander):
    commander.policy = lambda step, s: commander.servo_policy(step, s) if step < 30 else None
    commander.wait(commander.fault, what='fault')
    assert 'missing command for x_c y_c z_c x_f y_f z_f a_f b_f c_f' in commander.hw_diag[1]
    assert 'no answer to step 30' in commander.hw_diag[1]


def test_malformed_commands_are_refused_and_change_nothing(commander):
    from machine_ctrl.ros import messages as ros_io

    def policy(step, state):
        if step == 10:   # unknown axis, duplicate names, length mismatch, future stamp
            stamp = state.header.stamp
            for names, values in ((['x_c', 'nope'], [0.0, 0.0]), (['x_c', 'x_c'], [0.0, 0.0]), (['x_c'], [0.0, 1.0])):
                commander.pub.publish(ros_io.joint_state(stamp, names, effort=values))
            future = ros_io.StepClock(1e-4).stamp(step + 5)
            commander.pub.publish(ros_io.joint_state(future, commander.axes, effort=[0.0] * 9))
        return commander.servo_policy(step, state)
    commander.policy = policy
    commander.wait(lambda: commander.hw_diag is not None and int(commander.hw_diag[2]['refused_commands']) >= 4
                   and max(commander.steps) > 30, what='refusals')
    assert not commander.fault(), commander.hw_diag


PACED_FACTOR = 0.02
PACED_PERIOD = 1e-4 / PACED_FACTOR      # s of wall time per step of 0.1 ms: 200 steps/s


@pytest.fixture
def paced_commander(micromill, ros_node, ros_supervisor):
    launched = time.monotonic()         # hw_sim's pace starts after this (one monotonic clock for all processes)
    ros_supervisor.start('hw_sim', [sys.executable, '-m', 'machine_ctrl.ros.hw_sim_node', '--ros-args', '-p', 'mode:=paced',
                                    '-p', f'real_time_factor:={PACED_FACTOR}'])
    ros_supervisor.wait_for_line('hw_sim', 'ready', 60)
    c = Commander(ros_node('servos'), list(micromill.axis_names), micromill)
    c.launched = launched
    yield c
    c.stop()


def test_paced_mode_steps_on_the_wall_clock_and_counts_missed_deadlines(paced_commander):
    c = paced_commander
    # the servos answer, except for steps 100-109: those miss their deadline (9 axes each)
    c.policy = lambda step, state: None if 100 <= step < 110 else c.servo_policy(step, state)
    c.wait(lambda: c.steps and max(c.steps) > 120 and c.hw_diag is not None
           and int(c.hw_diag[2]['missed_deadlines']) >= 90, what='missed deadlines')
    assert not c.fault()            # paced mode holds the last command instead of faulting
    # never faster than the pace (a loaded machine only makes it slower, so no lower bound):
    # step k is due k periods after hw_sim's start, which came after `launched`, and a late
    # step shifts the schedule later, never earlier (hw_sim/pacing.py); + 1: the due
    # tolerance and the period's whole ns. Enough steps that the slack of hw_sim's start-up
    # (0.6 s idle: ~130 steps) does not hide a pace 20 % too fast.
    c.wait(lambda: max(c.steps) > 1000, timeout=120, what='1000 paced steps')
    step = max(c.steps)
    assert step < (time.monotonic() - c.launched) / PACED_PERIOD + 1


@pytest.mark.parametrize('args, message', [
    (['-p', 'mode:=turbo'], 'mode: must be lockstep or paced'),
    (['-p', 'real_time_factor:=2.0'], 'real_time_factor: must be in (0, 1], got 2.0'),
    (['-p', 'initial_position:=[0.0,0.0]'], 'initial_position needs 9 finite values'),
    (['-p', 'initial_position:=[0.9,0.0,0.0,0.0,0.0,0.0,0.0,0.0,0.0]'], 'outside the stroke of x_c'),
    (['-p', 'machine:=nosuch'], 'nosuch: unknown machine'),
    (['-p', 'recorder_window:=-1'], 'recorder_window: must be >= 0 steps, got -1'),
    (['-p', 'mode:=paced', '-p', 'recorder_window:=100'], 'recorder_window: needs mode lockstep'),
    (['-p', 'wait_for_recorder:=true'], 'wait_for_recorder: needs recorder_window > 0, got 0'),
])
def test_bad_parameters_stop_start_up_with_one_line(ros_env, args, message):
    import subprocess
    result = subprocess.run([sys.executable, '-m', 'machine_ctrl.ros.hw_sim_node', '--ros-args', *args], env=ros_env,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    fatal = [line for line in result.stderr.splitlines() + result.stdout.splitlines() if 'FATAL' in line]
    assert len(fatal) == 1 and message in fatal[0], result.stderr


@pytest.fixture
def gated_commander(micromill, ros_node, ros_supervisor):
    yield from _commanded_hw_sim(micromill, ros_node, ros_supervisor, 'recorder_window:=50')


def test_recorder_window_holds_the_machine_without_a_fault_until_the_recorder_catches_up(gated_commander, ros_node):
    from builtin_interfaces.msg import Time

    from machine_ctrl.ros.recorder_node import PROGRESS_QOS
    from machine_ctrl.ros.messages import StepClock
    c, clock = gated_commander, StepClock(1e-4)
    c.wait(lambda: c.steps and max(c.steps) > 100, what='running without a recorder')
    progress = ros_node('recorder').create_publisher(Time, contract.RECORDER_PROGRESS.name, PROGRESS_QOS)
    progress.publish(Time())                                   # a recorder at step 0: hold from step 51 on
    # held, as hw_sim reports it, for longer than command_timeout (by hw_sim's clock) ...
    c.wait(lambda: c.hw_diag is not None and c.hw_diag[2].get('holding_for_recorder') == 'True'
           and float(c.hw_diag[2]['recorder_hold_time']) > 0.5, what='a hold longer than command_timeout')
    held = int(c.hw_diag[2]['step'])
    # ... the state re-sent (every 0.1 s; waited for, not counted in a window: run101 saw 3
    # re-sends in the second a loaded host gave), the step still the held one, no fault
    c.wait(lambda: c.steps.count(held) > 3, what='the held state re-sent')
    assert not c.fault() and max(c.steps) == held, c.hw_diag
    progress.publish(clock.stamp(held - 40))                   # may run to held - 40 + 51
    # the hold at `held` ends with this report (same callback): held again with it, hw_sim
    # is at the step the window allows
    c.wait(lambda: c.hw_diag[2]['recorder_step'] == str(held - 40) and c.hw_diag[2]['holding_for_recorder'] == 'True',
           what='held again')
    assert c.hw_diag[2]['step'] == str(held + 11), c.hw_diag
    c.wait(lambda: c.steps.count(held + 11) > 3, what='the new held state re-sent')
    assert max(c.steps) == held + 11 and not c.fault()
    reasons = ('not on the 100000 ns control grid', f'progress for step {held + 500}, but the published steps are',
               'nanosec 1500000000 is not in [0, 1e9)')
    for i, (bad, reason) in enumerate(zip((Time(sec=0, nanosec=1), clock.stamp(held + 500),
                                           Time(sec=0, nanosec=1_500_000_000)), reasons)):
        progress.publish(bad)                                  # depth 1: one at a time
        c.wait(lambda: int(c.hw_diag[2]['refused_progress']) == i + 1, what=f'refused progress {i}')
        assert reason in c.hw_diag[2]['last_progress_refusal']
    assert max(c.steps) == held + 11 and c.hw_diag[2]['recorder_step'] == str(held - 40)
    assert c.hw_diag[2]['step'] == str(held + 11), c.hw_diag
    progress.destroy()                                         # the recorder leaves: no more holding
    c.wait(lambda: max(c.steps) > held + 200, what='running again once the recorder left')
    assert not c.fault()
