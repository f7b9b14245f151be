"""Two hosts ([7/8] part 4; README "Two hosts"): hw_sim, the drives' side, in one Linux network
namespace; the rest of the trt_5axis graph, the recorder and the client in another; the two
joined only by a veth pair (10.213.N.1 and .2/24). Discovery by ROS_AUTOMATIC_DISCOVERY_RANGE=
SUBNET with ROS_STATIC_PEERS naming the other side, and UDP only
(FASTDDS_BUILTIN_TRANSPORTS=UDPv4: the namespaces share /dev/shm, which two real hosts do not).

A part program runs (`machine-ctrl send circle.ngc`, test_gcode.py's circle), the bag is complete (every step recorded,
none lost), and the veth counters show the lock-step traffic crossed the link. Then the link
goes down for longer than hw_sim's command_timeout: hw_sim faults on the missing commands;
up again, a reset (/hw_sim/reset from the controller's side) and a move continue. Skipped
with the reason where network namespaces cannot be made (not root, no `ip`)."""
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from machine_ctrl import contract
from machine_ctrl.app.bringup import graph_specs, recorder_spec
from machine_ctrl.app.processes import Supervisor
from machine_ctrl.recording import cdr
from machine_ctrl.recording.bag import Bag
from machine_ctrl.ros.graph import write_specs
from test_gcode import CIRCLE

EXE = str(Path(sys.executable).with_name('machine-ctrl'))
COMMAND_TIMEOUT = 5.0            # s: hw_sim's default (parameters.HW_SIM)


def _ip(*args, check=True) -> subprocess.CompletedProcess:
    return subprocess.run(['ip', *args], capture_output=True, text=True, check=check, timeout=30)


def _netns_problem() -> str | None:
    if shutil.which('ip') is None:
        return 'no `ip` command (iproute2) to make network namespaces'
    probe = f'mcprobe{os.getpid()}'
    made = _ip('netns', 'add', probe, check=False)
    if made.returncode != 0:
        return f'cannot make a network namespace (needs root / CAP_SYS_ADMIN): {made.stderr.strip()}'
    _ip('netns', 'del', probe, check=False)
    return None


class Hosts:
    """Two network namespaces and the veth pair between them."""

    def __init__(self):
        tag = os.getpid() % 100000
        self.drives, self.control = f'mcdrv{tag}', f'mcctl{tag}'        # namespace names
        self.drives_link, self.control_link = f'mvd{tag}', f'mvc{tag}'  # veth ends (<= 15 characters)
        subnet = f'10.213.{tag % 250}'
        self.drives_ip, self.control_ip = f'{subnet}.1', f'{subnet}.2'
        try:
            for ns in (self.drives, self.control):
                _ip('netns', 'add', ns)
            _ip('link', 'add', self.drives_link, 'type', 'veth', 'peer', 'name', self.control_link)
            for ns, link, ip in ((self.drives, self.drives_link, self.drives_ip),
                                 (self.control, self.control_link, self.control_ip)):
                _ip('link', 'set', link, 'netns', ns)
                _ip('-n', ns, 'addr', 'add', f'{ip}/24', 'dev', link)
                _ip('-n', ns, 'link', 'set', link, 'up')
                _ip('-n', ns, 'link', 'set', 'lo', 'up')
        except subprocess.CalledProcessError:
            self.close()
            _ip('link', 'del', self.drives_link, check=False)      # if it was made but not moved
            raise

    def env(self, base: dict, peer: str) -> dict:
        return {**base, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET', 'ROS_STATIC_PEERS': peer,
                'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'}

    def bytes_sent(self, ns: str, link: str) -> int:
        done = subprocess.run(['ip', 'netns', 'exec', ns, 'cat', f'/sys/class/net/{link}/statistics/tx_bytes'],
                              capture_output=True, text=True, check=True, timeout=30)
        return int(done.stdout)

    def close(self) -> None:
        for ns in (self.drives, self.control):         # deleting a namespace deletes its veth end
            _ip('netns', 'del', ns, check=False)


@pytest.fixture
def hosts(ros_env):
    problem = _netns_problem()
    if problem:
        pytest.skip(problem)
    made = Hosts()
    try:
        yield made
    finally:
        made.close()


def test_hw_sim_on_one_host_the_controllers_on_another(hosts, ros_env, trt, tmp_path):
    bag = tmp_path / 'bag'
    specs = graph_specs(trt, record=True)
    rest = [spec for spec in specs if spec.name != 'hw_sim']
    hw = next(spec for spec in specs if spec.name == 'hw_sim')
    drives_env = hosts.env(ros_env, hosts.control_ip)
    control_env = hosts.env(ros_env, hosts.drives_ip)
    on_drives, on_control = ['ip', 'netns', 'exec', hosts.drives], ['ip', 'netns', 'exec', hosts.control]

    def control(*argv, timeout=700) -> subprocess.CompletedProcess:
        return subprocess.run([*on_control, *argv], env=control_env, capture_output=True, text=True,
                              timeout=timeout, stdin=subprocess.DEVNULL)

    with Supervisor(drives_env, log_dir=tmp_path / 'drives', stop_timeout=5.0) as drives, \
            Supervisor(control_env, log_dir=tmp_path / 'control', stop_timeout=5.0) as controllers:
        controllers.start('recorder', [*on_control, *recorder_spec(trt, str(bag), specs).argv(tmp_path)])
        controllers.start('graph', [*on_control, sys.executable, '-m', 'machine_ctrl.ros.graph', '--specs',
                                    str(write_specs(rest, tmp_path / 'control.yaml'))])
        drives.start('hw_sim', [*on_drives, *hw.argv(tmp_path)])
        drives.wait_for_line('hw_sim', 'graph ready at step', timeout=180)
        sent_before, path_start = hosts.bytes_sent(hosts.control, hosts.control_link), time.time_ns()
        program = tmp_path / 'circle.ngc'
        program.write_text(CIRCLE)
        done = control(EXE, 'send', str(program), '--machine', 'trt_5axis', '--timeout', '600')
        assert done.returncode == 0, done.stdout + done.stderr
        crossed, path_end = hosts.bytes_sent(hosts.control, hosts.control_link) - sent_before, time.time_ns()

        # the link down for longer than hw_sim's command_timeout: hw_sim faults on the
        # controllers' missing commands (the controllers' side loses hw_sim: README "Two hosts")
        _ip('-n', hosts.drives, 'link', 'set', hosts.drives_link, 'down')
        drives.wait_for_line('hw_sim', 'FAULT, machine stopped: missing command for', timeout=180)
        _ip('-n', hosts.drives, 'link', 'set', hosts.drives_link, 'up')
        reset = control(sys.executable, '-c', RESET.format(machine='trt_5axis', service=contract.RESET.name),
                        timeout=300)
        assert reset.returncode == 0 and 'reset: True' in reset.stdout, reset.stdout + reset.stderr
        moved = control(EXE, 'move', 'x=0.002', '--machine', 'trt_5axis', '--timeout', '600')
        assert moved.returncode == 0, moved.stdout + moved.stderr
        # the graph first, then the recorder (as bringup stops them: the recorder drains until
        # its publishers are gone, at most 30 s)
        for supervisor, name in ((drives, 'hw_sim'), (controllers, 'graph'), (controllers, 'recorder')):
            supervisor.children[name].signal_group(signal.SIGINT)
            assert supervisor.wait(name, timeout=120) == 0, name

    clock = contract.StepClock(trt.control_period)
    with Bag(bag) as recorded:
        states = [(m.log_time, cdr.JointStateDecoder().decode(m.data)) for m in recorded.messages(['/joint_states'])]
        lost = {k: v for k, v in recorded.custom_data.items() if k.startswith('machine_ctrl.lost')}
    stamps = [log_time for log_time, _ in states]
    recorded_steps = [clock.step_at(state.sec, state.nanosec) for _, state in states]
    steps = len(stamps)
    during = sum(path_start <= t <= path_end for t in stamps)     # log times: the recorder's wall clock
    print(f'{steps} joint states recorded; during the path {crossed / 1e6:.1f} MB sent over the link and '
          f'{during / contract.ns_to_seconds(path_end - path_start):.0f} steps/s (wall; the send command\'s own start '
          'included)')
    assert steps > 2500, steps                  # the circle: 2.3 s at 1 kHz
    # the recorder's loss check of both stamped streams (each recorded: its key is there): none lost
    assert lost == {'machine_ctrl.lost/joint_states': '0', 'machine_ctrl.lost/clock': '0'}, lost
    # every step there, in order (a held step's state is re-sent by hw_sim until answered)
    assert sorted(set(recorded_steps)) == list(range(recorded_steps[-1] + 1))
    assert recorded_steps == sorted(recorded_steps)
    assert crossed > 2500 * 100                 # every step's commands crossed (a servo command alone is > 100 bytes)


# /hw_sim/reset from the controllers' side, once the controllers hear hw_sim again
RESET = '''
from machine_ctrl.app.bringup import client_session
from machine_ctrl.model.config import load_machine
with client_session(load_machine({machine!r}), 'two_hosts_reset') as client:
    client.wait_ready(timeout=120)
    ok, message = client.call({service!r}, timeout=60)
    print('reset:', ok, message)
    # the trajectory node takes goals again once it has heard hw_sim alive again (its liveliness,
    # lost while the link was down) and healthy: wait for that, as a user waits for 'idle'
    client.wait(lambda: client.status().get('state') == 'idle', 'the trajectory node idle after the reset', 120)
'''
