"""robot_piezo ([4/8]) offline: how closely the true tool tip follows the path, the arm's
deflection under the milling force included (hw_sim/tool_deflection.py), with the coupling
off, reading the robot's deviation from its encoders (the config's tracker and mid-ranging
removed), reading it from the tracker (mid-ranging removed), and with the tracker and the
mid-ranging (the config as it is). Accuracy, not speed: no baseline.

Per path: hw_sim.offline_goal.run_goal (the trajectory node's session and the graph's laws,
as test_robot_piezo.py's face runs), every 10th step from the motion's start to the run's end
(one chunk past the motion: the arm's ring-down after the stop included); |P_ref - P_true|
with P_true the forward kinematics of the true axis positions plus the deflection along the
workpiece's z. Prints a Markdown table (µm); "stage offset" is the piezo stage's offset at
the motion's end and its largest over the run, |J_P,fine dq_f| (what mid-ranging returns to 0).

    .venv/bin/python bench/robot_piezo_paths.py
"""
from __future__ import annotations

import dataclasses

import numpy as np

from hw_sim.offline_goal import run_goal
from hw_sim.simulator import true_geometry
from hw_sim.tool_deflection import deflections
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics
from trajectory import toolpath


def paths():
    line = toolpath.from_arrays(np.linspace([0.0, 0.0, 0.0], [-3e-3, 0.0, 0.0], 31), np.tile([0.0, 0.0, 1.0], (31, 1)))
    return (('3 mm line into the block (test_robot_piezo_graph)', line, 0.010),
            ('1 mm circle (test_robot_piezo)', toolpath.circle_xy(radius=0.5e-3, points=91), 7.5e-3),
            ('4 mm circle_xy', toolpath.circle_xy(), 0.010))


def main() -> None:
    machine = load_machine('robot_piezo')
    kinematics = Kinematics.from_config(machine)
    tracker = dataclasses.replace(machine, cartesian_dual_stage=dataclasses.replace(
        machine.cartesian_dual_stage, midranging=None))
    encoders = dataclasses.replace(tracker, cartesian_dual_stage=dataclasses.replace(
        tracker.cartesian_dual_stage, tracker=None))
    fine = [machine.axis_names.index(a) for a in machine.fine_axes]
    print('| path | feed mm/s | coupling | mean | rms | max | max deflection | fine-stroke clips '
          '| stage offset at the end / max |')
    print('|---|---|---|---|---|---|---|---|---|')
    for name, cl, feed in paths():
        for label, config, on in (('off', machine, False), ('encoders', encoders, True), ('tracker', tracker, True),
                                  ('tracker, mid-ranging', machine, True)):
            run = run_goal(config, cl, feed=feed, dual_stage=on)
            record = run.record
            if run.goal_state != 'succeeded' or record.fault:
                print(f'| {name} | {feed * 1e3:g} | {label} | {run.goal_state}: {record.fault} |')
                continue
            d = deflections(config, true_geometry(config), record.true)
            rows = range(run.motion_start, len(record.true), 10)
            e = np.array([np.linalg.norm(kinematics.forward(record.reference[k])[0] - kinematics.forward(record.true[k])[0]
                                         - [0.0, 0.0, d[k]]) for k in rows]) * 1e6
            stage = np.array([np.linalg.norm(kinematics.jacobian(record.reference[k])[:3, fine]
                                             @ record.offsets[k, :len(fine)]) for k in rows]) * 1e6
            end = stage[(run.motion_end - run.motion_start) // 10]
            print(f'| {name} | {feed * 1e3:g} | {label} | {e.mean():.1f} | {np.sqrt(np.mean(e * e)):.1f} | {e.max():.1f} '
                  f'| {np.abs(d).max() * 1e6:.1f} | {record.saturations} | {end:.1f} / {stage.max():.1f} |')


if __name__ == '__main__':
    main()
