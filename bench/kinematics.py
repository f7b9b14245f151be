"""Cost of P, O and J per call, beside the bare Pinocchio calls they wrap, measured in the
same run; the ratio is our overhead (q mapping, frame composition, column selection).

    .venv/bin/python bench/kinematics.py [MACHINE]
"""
import sys
import timeit

import numpy as np
import pinocchio as pin

from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics


def best_per_call(fn, number=2000, repeat=7):
    return min(timeit.repeat(fn, number=number, repeat=repeat)) / number


def main(machine_name='micromill_9axis'):
    machine = load_machine(machine_name)
    kin = Kinematics.from_config(machine)
    model, data = kin.model, kin.data
    fw, ft = model.getFrameId(machine.workpiece_frame), model.getFrameId(machine.tool_frame)
    q = np.array([0.5 * (a.stroke[0] + a.stroke[1]) + 0.1 * (a.stroke[1] - a.stroke[0])
                  if a.stroke else 0.3 for a in machine.axes])
    q_pin = kin.pin_configuration(q)
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

    def bare_forward():
        pin.forwardKinematics(model, data, q_pin)
        pin.updateFramePlacement(model, data, fw)
        pin.updateFramePlacement(model, data, ft)

    def bare_jacobian():
        pin.computeJointJacobians(model, data, q_pin)
        pin.updateFramePlacement(model, data, fw)
        pin.updateFramePlacement(model, data, ft)
        pin.getFrameJacobian(model, data, fw, lwa)
        pin.getFrameJacobian(model, data, ft, lwa)

    rows = [
        ('P, O         forward()', best_per_call(lambda: kin.forward(q)), best_per_call(bare_forward)),
        ('P, O, J      forward_and_jacobian()', best_per_call(lambda: kin.forward_and_jacobian(q)),
         best_per_call(bare_jacobian)),
        ('wT_t         tool_pose()', best_per_call(lambda: kin.tool_pose(q)), best_per_call(bare_forward)),
    ]
    print(f'machine {machine.name} ({len(machine.axes)} axes, pinocchio {pin.__version__})')
    print(f'{"call":40s} {"ours us":>9s} {"bare pin us":>12s} {"ratio":>7s}')
    for name, ours, bare in rows:
        print(f'{name:40s} {ours * 1e6:9.2f} {bare * 1e6:12.2f} {ours / bare:7.2f}')


if __name__ == '__main__':
    main(*sys.argv[1:])
