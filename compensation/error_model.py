"""Error-augmented forward kinematics (Yuen thesis, seed 000_d9dd5f6a818770e4.txt, §5.2,
Eqs. 5.1-5.7), evaluated for many configurations at once.

The chain is the ideal one of :class:`machine_ctrl.model.kinematics.Kinematics`, walked by
machine_ctrl/model/chain.py (one definition of the machine, read from its Pinocchio model),
with each joint's errors added after its motion. Each joint j contributes

    placement_j  motion_j(q_j)  E_j(q_j)                                    (Eqs. 5.3-5.5)

with E_j the error matrix of Eq. (5.1) (small-angle form, exactly as printed) built from the
axis's error functions (compensation.error_map), post-multiplied as in Eq. (5.3). The two
chains base->workpiece (Eq. 5.4) and base->tool tip (Eq. 5.5) give

    T_a = (^B T_w,a)^-1 ^B T_t,a,    P_a = translation of T_a               (Eqs. 5.6-5.7)

Everything is batched over the rows of Q (N x n) with numpy, so compensating a whole chunk
of reference rows costs a few array operations per joint, not N Pinocchio calls. With all
errors zero the result equals the ideal kinematics to rounding (tested, <= 1e-15 m).

The Jacobian of P_a with respect to some axes (the compensating Jacobian J^c of Eq. 5.20)
is exact for axes whose own error functions are zero: the errors of the other axes are
constant with respect to them. The compensator checks that (compensate.py).
"""
from __future__ import annotations

import numpy as np

from compensation.error_map import DIRECTIONS, ErrorMap
from machine_ctrl.model.chain import ChainJoint, chain, end_frame, walk
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.model.kinematics import Kinematics

def _error_matrix(errors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation part I + skew(eps) and translation delta of Eq. (5.1), (N, 3, 3) and (N, 3)."""
    ex, ey, ez = errors[:, 3], errors[:, 4], errors[:, 5]
    rot = np.zeros((errors.shape[0], 3, 3))
    rot[:, 0, 0] = rot[:, 1, 1] = rot[:, 2, 2] = 1.0
    rot[:, 0, 1], rot[:, 0, 2] = -ez, ey
    rot[:, 1, 0], rot[:, 1, 2] = ez, -ex
    rot[:, 2, 0], rot[:, 2, 1] = -ey, ex
    return rot, errors[:, :3]


class ErrorKinematics:
    """P_a(q) and J^c(q) of a machine with a geometric error map (None: the ideal machine)."""

    def __init__(self, kinematics: Kinematics, workpiece_frame: str, tool_frame: str,
                 error_map: ErrorMap | None = None):
        self.axis_names = kinematics.axis_names
        self.error_map = error_map or ErrorMap()
        self._workpiece, workpiece_end = chain(kinematics.model, self.axis_names, workpiece_frame)
        self._tool, tool_end = chain(kinematics.model, self.axis_names, tool_frame)
        self._workpiece_frame, self._tool_frame = end_frame(workpiece_end), end_frame(tool_end)
        by_name = {j.name: j for j in self._workpiece + self._tool}
        self._errors = dict(self.error_map.axes)                  # axis -> its error functions
        self._squareness = {name: np.zeros(3) for name in by_name}   # sum of gamma * (e_about x axis)
        for sq in self.error_map.squareness:
            joint = by_name[sq.axis]
            about = np.zeros(3)
            about[DIRECTIONS[sq.about]] = 1.0
            if not joint.prismatic:
                raise ConfigError(f'{self.error_map.source}: squareness of {sq.axis}: '
                                  'only linear axes have a squareness error')
            self._squareness[sq.axis] = self._squareness[sq.axis] + sq.angle * np.cross(about, joint.axis)
        for joint in by_name.values():
            joint.motion = joint.axis + self._squareness[joint.name]
            joint.freeze()

    @classmethod
    def from_config(cls, machine: MachineConfig, error_map: ErrorMap | None = None,
                    kinematics: Kinematics | None = None) -> ErrorKinematics:
        return cls(kinematics or Kinematics.from_config(machine), machine.workpiece_frame,
                   machine.tool_frame, error_map)

    def _joint(self, axis: str) -> ChainJoint:
        return next(j for j in self._workpiece + self._tool if j.name == axis)

    def has_errors(self, axis: str) -> bool:
        return axis in self._errors or bool(self._squareness[axis].any())

    def direction(self, axis: str) -> int:
        """Index (0 x, 1 y, 2 z) of the axis's direction of motion in its own frame."""
        return int(np.argmax(self._joint(axis).axis))

    def axis_errors(self, axis: str, q) -> np.ndarray:
        """(N, 6) [dx dy dz ex ey ez] of one axis at positions q, squareness included (as the
        straightness it causes relative to the nominal directions)."""
        q = np.asarray(q, float)
        out = self._errors[axis].evaluate(q) if axis in self._errors else np.zeros((len(q), 6))
        out[:, :3] += self._squareness[axis] * q[:, None]
        return out

    def _walk(self, joints, frame, q, want):
        """machine_ctrl.model.chain.walk with each joint's errors after its motion (Eq. 5.3)."""
        return walk(joints, frame, q, want, self._with_errors)

    def _with_errors(self, joint, qj, rot, pos):
        errors = self._errors.get(joint.name)
        if errors is None:
            return rot, pos
        e_rot, e_pos = _error_matrix(errors.evaluate(qj))
        return rot @ e_rot, pos + np.einsum('nij,nj->ni', rot, e_pos)

    def tool_poses(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Rotation (N, 3, 3) and tool-tip position P_a (N, 3) of ^wT_t,a (Eqs. 5.6-5.7)."""
        q = np.atleast_2d(np.asarray(q, float))
        rw, pw, _ = self._walk(self._workpiece, self._workpiece_frame, q, ())
        rt, pt, _ = self._walk(self._tool, self._tool_frame, q, ())
        rwt = np.swapaxes(rw, 1, 2)
        return rwt @ rt, np.einsum('nij,nj->ni', rwt, pt - pw)

    def positions(self, q) -> np.ndarray:
        """Tool-tip positions P_a (N, 3), m, in the workpiece frame."""
        return self.tool_poses(q)[1]

    def tool_pose(self, q) -> np.ndarray:
        """4 x 4 ^wT_t,a of one configuration."""
        rot, pos = self.tool_poses(q)
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = rot[0], pos[0]
        return out

    def positions_and_jacobian(self, q, axes) -> tuple[np.ndarray, np.ndarray]:
        """P_a (N, 3) and dP_a/dq_axes (N, 3, len(axes)) (J^c, Eq. 5.20, for the fine axes).
        A joint moving the workpiece by dq moves the tip relative to it by -(a dq) for a
        prismatic joint and by -(a x (p_t - o)) dq for a revolute one (a: axis, o: a point on
        it, base frame); a joint of the tool chain by the same with + sign."""
        q = np.atleast_2d(np.asarray(q, float))
        rw, pw, w_axes = self._walk(self._workpiece, self._workpiece_frame, q, axes)
        rt, pt, t_axes = self._walk(self._tool, self._tool_frame, q, axes)
        rwt = np.swapaxes(rw, 1, 2)
        columns = []
        for name in axes:
            sign, (a, o) = (-1.0, w_axes[name]) if name in w_axes else (1.0, t_axes[name])
            joint = self._joint(name)
            moved = a if joint.prismatic else np.cross(a, pt - o)
            columns.append(sign * np.einsum('nij,nj->ni', rwt, moved))
        return np.einsum('nij,nj->ni', rwt, pt - pw), np.stack(columns, axis=2)
