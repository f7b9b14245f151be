"""``ros2 launch machine_ctrl bringup.launch.py``: the graph of ``machine-ctrl bringup``.

Arguments (``name:=value``):

* ``machine`` — machine name (config/machines/) or YAML path; default micromill_9axis.
* ``namespace`` — ROS namespace of the whole graph (e.g. ``mill2``); default the root.
  Every name is relative, the sim clock included, so machines in different namespaces share
  a ROS domain without cross-talk (README "For ROS users", "Namespaces").
* ``record`` — bag directory to record the session into (absent or empty); default: no
  recording. In lock-step hw_sim then holds at step 0 until the recorder is there and keeps
  within its window, as with ``machine-ctrl bringup --record``; paced, it waits for no one
  (the recorder may miss states).
* ``paced`` — a real-time factor in (0, 1]: hw_sim steps on the wall clock (README "Paced
  mode"); default lock-step.
* ``dual_stage`` — ``true``/``false``: the dual-stage coupling at start; default true.
* ``compensation`` — geometric error model (YAML of ``machine-ctrl fit-errors``): the
  compensation node sits between the trajectory node and the servos; default none.
* ``identified`` — belief files of ``machine-ctrl identify --out``, comma-separated (``~``
  expanded; a path may not hold a comma): the
  servo nodes' ``belief`` parameter, the controllers' values over the config's (README
  "Identification"), as ``machine-ctrl bringup --identified``; hw_sim keeps the plant. A file
  that cannot be read or sets anything else stops the launch before any node starts, with the
  reason. Default none.
* ``params_file`` — a ROS parameters file applied after the graph's own values (e.g.
  ``config/params/<machine>.yaml`` edited, or a ``ros2 param dump``); default none.
* ``robot_state_publisher`` — ``true`` starts robot_state_publisher (TF for RViz) when it is
  installed (ROS from apt; not on PyPI); default false.
* ``respawn`` — ``true`` (default): a controller node that dies (servo, dual_stage, trajectory,
  compensation, contour_error; an exit status other than 0) is started again as
  ``machine-ctrl bringup`` does (machine_ctrl.app.bringup: ``respawn_delay``, 8.5 s after its
  death by default; a ``params_file``'s ``command_timeout`` is not read here; at most
  ``RESPAWN_MAX`` times); a node that exits 0 was asked to stop. hw_sim (the machine: its
  state would be lost) and the recorder (its bag directory is not empty any more) are not
  respawned. A dead servo or dual_stage node
  faults hw_sim (its commands stop); once the respawned node answers the held step,
  ``hw_sim/reset`` continues, and nothing moves again without a new goal.

The graph is the same data as ``machine-ctrl bringup`` builds
(:func:`machine_ctrl.app.bringup.graph_specs`): each node a process of its own, with its
parameters and remappings. Ctrl-C or SIGTERM: launch signals every node, each shuts down
at once and exits 0; the recorder drains and closes the bag first (launch waits up to
``RECORDER_STOP_TIMEOUT`` s, 60, for it before its SIGTERM, as ``machine-ctrl bringup`` does).
"""
from __future__ import annotations

import os

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, LogInfo, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

ARGUMENTS = (
    ('machine', 'micromill_9axis', 'machine name (config/machines/) or YAML path'),
    ('namespace', '', 'ROS namespace of the graph (default: the root)'),
    ('record', '', 'bag directory to record into (default: no recording)'),
    ('paced', '', 'hw_sim steps on the wall clock at this real-time factor, in (0, 1] (default: lock-step)'),
    ('dual_stage', 'true', 'dual-stage coupling on at start (true/false)'),
    ('compensation', '', 'geometric error model YAML: compensation on (default: off)'),
    ('identified', '', 'belief files of machine-ctrl identify --out, comma-separated: the servos\' values'),
    ('params_file', '', 'ROS parameters file applied after the graph\'s values'),
    ('robot_state_publisher', 'false', 'start robot_state_publisher when installed (true/false)'),
    ('respawn', 'true', 'start a dead controller node again (not hw_sim, not the recorder)'),
)


def _flag(name: str, text: str) -> bool:
    if text.lower() in ('true', '1', 'yes', 'on'):
        return True
    if text.lower() in ('false', '0', 'no', 'off'):
        return False
    raise ValueError(f'launch argument {name}:={text!r} must be true or false')


def _factor(text: str) -> float | None:
    """paced:= as a number (None: empty, lock-step); its range is checked with hw_sim's parameter."""
    if not text.strip():
        return None
    try:
        return float(text)
    except ValueError:
        raise ValueError(f'launch argument paced:={text!r} must be a real-time factor in (0, 1]') from None


def _executable(spec) -> str:
    return spec.module.rsplit('.', 1)[-1]          # setup.py EXECUTABLES: the module's name


def _nodes(context):
    from machine_ctrl import contract
    from machine_ctrl.app.bringup import (NOT_RESPAWNED, RECORDER_STOP_TIMEOUT, RESPAWN_MAX, graph_specs,
                                          recorder_spec, respawn_delay)
    from machine_ctrl.model.config import load_machine
    from machine_ctrl.ros.graph import write_params_file

    value = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    machine = load_machine(value['machine'])
    belief = [os.path.expanduser(path.strip()) for path in value['identified'].split(',') if path.strip()]
    if value['identified'].strip() and not belief:
        raise ValueError(f"launch argument identified:={value['identified']!r} names no file")
    if belief:                          # a bad belief file: the reason here, before any node starts
        load_machine(value['machine'], belief=belief)
    namespace = contract.normal_namespace(value['namespace'])
    record = value['record'] or None
    specs = graph_specs(machine, _flag('dual_stage', value['dual_stage']), value['compensation'] or None,
                        record is not None, namespace=namespace, belief=belief, paced=_factor(value['paced']))
    if record is not None:
        from machine_ctrl.app.cli.common import fresh_directory
        fresh_directory(record)
        specs.append(recorder_spec(machine, record, specs, namespace=namespace))
    extra = [value['params_file']] if value['params_file'] else []
    # the graph's values as our own parameters file (strings quoted: rcl reads a bare y as true)
    respawn = _flag('respawn', value['respawn'])
    delay = respawn_delay(specs)
    actions = []
    for spec in specs:
        params = [str(write_params_file([spec], None, spec.name)), *extra]

        # the recorder may take long to drain and close a long session's bag: launch's
        # SIGTERM waits as long as machine-ctrl bringup's does (a loaded run's recorder got
        # SIGTERM after launch's default 5 s while closing a bag of 316k messages)
        grace = {'sigterm_timeout': str(RECORDER_STOP_TIMEOUT)} if spec.name == 'recorder' else {}

        def make(spec=spec, params=params, grace=grace):
            return Node(package='machine_ctrl', executable=_executable(spec), name=spec.name,
                        namespace=spec.namespace or None, parameters=params,
                        remappings=[contract.CLOCK_REMAP], output='screen', emulate_tty=True, **grace)
        actions += _respawned(make, delay, RESPAWN_MAX) if respawn and spec.name not in NOT_RESPAWNED else [make()]
    if _flag('robot_state_publisher', value['robot_state_publisher']):
        actions.append(_robot_state_publisher(machine, namespace))
    return actions


def _respawned(make, delay: float, retries: int) -> list:
    """The node `make()` makes, and a handler that starts a new one `delay` s after it died,
    at most `retries` more times. Died = an exit status other than 0: every node
    exits 0 when asked to stop (Ctrl-C, SIGTERM), so a terminal's Ctrl-C — which reaches the
    nodes at the same time as launch, and they may end before launch has begun its shutdown
    — never starts a node again (launch's own `respawn` would, and the node started after
    the shutdown was never stopped: `ros2 launch` hung)."""
    from launch.actions import RegisterEventHandler, TimerAction
    from launch.event_handlers import OnProcessExit

    node = make()

    def on_exit(event, context):
        if event.returncode == 0 or context.is_shutdown or retries <= 0:
            return None
        return [TimerAction(period=delay, actions=_respawned(make, delay, retries - 1))]
    return [node, RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit))]


def _robot_state_publisher(machine, namespace: str):
    """robot_state_publisher on our joint_states and sim clock, if installed."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    from machine_ctrl import contract
    try:
        get_package_prefix('robot_state_publisher')
    except PackageNotFoundError:
        return LogInfo(msg='robot_state_publisher is not installed (ROS from apt has it): not started')
    return Node(package='robot_state_publisher', executable='robot_state_publisher', namespace=namespace or None,
                parameters=[{'robot_description': machine.urdf_path.read_text(), 'use_sim_time': True}],
                remappings=[contract.CLOCK_REMAP], output='screen')


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([*(DeclareLaunchArgument(name, default_value=default, description=what)
                                for name, default, what in ARGUMENTS),
                              OpaqueFunction(function=_nodes)])
