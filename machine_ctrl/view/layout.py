"""The Foxglove layout of a machine's session (issue [7/8], part 3): the panels of the
analysis plots (machine_ctrl/recording/plots.py) over the view's channels
(machine_ctrl/view/live_view.py), for the live view and a viewed bag alike.

* 3D: the view's scene (contract.VIEW_SCENE), the commanded tool path and the measured
  tool-tip trace (path_xy.png, in 3D), in the machine's workpiece frame;
* Plot "tracking error": reference − measured per axis (errors.png, top);
* Plot "contour error": tool-tip and orientation contour error magnitudes (errors.png, bottom);
* Plot "axis positions": the measured positions from the joint states;
* Raw messages of the trajectory status and the goal status; the diagnostics summary.

A layout names its axes (the tracking error's fields, the joint state's columns), so there
is one per machine: config/foxglove/<machine>.json, written by ``python -m
machine_ctrl.view.layout --write config/foxglove`` (test/test_view.py checks they are
current). Foxglove: Layouts, "Import from file". Plain JSON, no foxglove import.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from machine_ctrl import contract
from machine_ctrl.model.config import MachineConfig, load_machine

MACHINES = ('micromill_9axis', 'trt_5axis', 'fts_lathe', 'robot_piezo')


def _plot(title: str, paths: list[tuple[str, str]]) -> dict:
    return {'title': title,
            'paths': [{'value': value, 'label': label, 'enabled': True, 'timestampMethod': 'receiveTime'}
                      for value, label in paths],
            'showXAxisLabels': True, 'showYAxisLabels': True, 'showLegend': True, 'legendDisplay': 'floating',
            'isSynced': True, 'xAxisVal': 'timestamp', 'sidebarDimension': 240}


def _split(direction: str, first, second, percent: float = 50) -> dict:
    return {'direction': direction, 'first': first, 'second': second, 'splitPercentage': percent}


def layout(machine: MachineConfig, namespace: str = '') -> dict:
    """The layout of `machine`'s session in `namespace` ('' or '/NS'), as Foxglove exports one."""
    ns = namespace.rstrip('/')

    def topic(t: contract.Topic) -> str:
        return f'{ns}/{t.name}'
    axes = machine.axis_names
    panels = {
        '3D!scene': {'followTf': machine.workpiece_frame, 'followMode': 'follow-pose', 'scene': {},
                     'topics': {contract.VIEW_SCENE: {'visible': True}}, 'layers': {}, 'transforms': {}, 'publish': {},
                     'cameraState': {'perspective': True, 'distance': 0.05, 'phi': 60, 'thetaOffset': 45,
                                     'target': [0, 0, 0], 'targetOffset': [0, 0, 0], 'fovy': 45, 'near': 0.0001,
                                     'far': 100}},
        'Plot!tracking': _plot('tracking error (reference - measured), m or rad',
                               [(f'{contract.VIEW_TRACKING_ERROR}.error.{axis}', axis) for axis in axes]),
        'Plot!contour': _plot('contour error', [
            (f'{topic(contract.CONTOUR_TOOL_TIP_MAGNITUDE)}.data', 'tool tip, m'),
            (f'{topic(contract.CONTOUR_ORIENTATION_MAGNITUDE)}.data', 'orientation, rad')]),
        'Plot!positions': _plot('axis positions (measured), m or rad',
                                [(f'{topic(contract.JOINT_STATES)}.position[{i}]', axis)
                                 for i, axis in enumerate(axes)]),
        'RawMessages!status': {'topicPath': topic(contract.TRAJECTORY_STATUS), 'diffEnabled': False,
                               'diffMethod': 'custom', 'diffTopicPath': '', 'showFullMessageForDiff': False,
                               'expansion': 'all'},
        'RawMessages!goals': {'topicPath': topic(contract.GOAL_STATUS), 'diffEnabled': False, 'diffMethod': 'custom',
                              'diffTopicPath': '', 'showFullMessageForDiff': False},
        'DiagnosticSummary!diagnostics': {'topicToRender': topic(contract.DIAGNOSTICS), 'pinnedIds': [],
                                          'hardwareIdFilter': '', 'sortByLevel': True},
    }
    arrangement = _split('row',
                         _split('column', '3D!scene', _split('row', 'RawMessages!status', 'RawMessages!goals'), 60),
                         _split('column', _split('column', 'Plot!tracking', 'Plot!contour'),
                                _split('column', 'Plot!positions', 'DiagnosticSummary!diagnostics')))
    return {'configById': panels, 'globalVariables': {}, 'userNodes': {}, 'playbackConfig': {'speed': 1.0},
            'layout': arrangement}


def text(machine: MachineConfig, namespace: str = '') -> str:
    """:func:`layout` as the JSON file Foxglove imports."""
    return json.dumps(layout(machine, namespace), indent=2) + '\n'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description='write the Foxglove layout of every shipped machine')
    parser.add_argument('--write', metavar='DIR', required=True)
    args = parser.parse_args(argv)
    directory = Path(args.write)
    directory.mkdir(parents=True, exist_ok=True)
    for name in MACHINES:
        (directory / f'{name}.json').write_text(text(load_machine(name)))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
