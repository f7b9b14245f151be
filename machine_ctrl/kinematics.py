"""Forward kinematics and Jacobian of any machine, built with Pinocchio from its URDF.

A machine is two kinematic chains from one base frame: the workpiece chain ending in the
workpiece frame and the tool chain ending in the tool-tip frame (Yuen thesis Eqs. 3.1-3.2).
In the workpiece frame (thesis Eqs. 3.4-3.5):

    ^wT_t(q) = (^BT_w)^-1 ^BT_t,   P(q) = tool-tip position,   O(q) = ^wR_t e_z (tool axis)

The analytic Jacobian J = d[P; O]/dq (thesis Eq. 3.13, 6 x n) is composed from Pinocchio's
frame Jacobians (LOCAL_WORLD_ALIGNED: world-frame linear velocity of the frame origin and
world angular velocity). With r = p_t - p_w and o = R_t e_z, both in the base frame:

    dP/dq = R_w^T (Jv_t - Jv_w + [r]x Jw_w)        (P = R_w^T r)
    dO/dq = -R_w^T [o]x (Jw_t - Jw_w)              (O = R_w^T o)

Axis coordinates are plain positions in m and rad for every joint type. A URDF continuous
joint has two configuration coordinates in Pinocchio (cos, sin); :meth:`pin_configuration`
does that mapping, so callers never see it.

Rank: O is a unit vector, so O^T dO/dq = 0 and the orientation rows of J have rank <= 2:
J has rank <= 5 everywhere and J J^T is always singular (seed-notes.md, "Jacobian rank").
This module returns the full 6 x n J. Code that inverts J uses the 5-D task instead,
:func:`task_jacobian`: the position rows plus the orientation rows projected on an
orthonormal basis of the plane normal to O (:func:`orientation_basis`). That task Jacobian
has full row rank 5 away from true singularities, and a 5-D task velocity is the exact image
of any orientation rate that keeps |O| = 1.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from machine_ctrl.config import MachineConfig
from machine_ctrl.errors import ConfigError

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class Kinematics:
    """P(q), O(q), ^wT_t(q) and J(q) for axis positions q (axis order of the machine config)."""

    def __init__(self, urdf_path: str | Path, axis_names, workpiece_frame: str, tool_frame: str):
        try:
            self.model = pin.buildModelFromUrdf(str(urdf_path))
        except Exception as exc:  # noqa: BLE001 - Pinocchio raises several types for bad files
            raise ConfigError(f'{urdf_path}: Pinocchio cannot build the model: '
                              f'{" ".join(str(exc).split())}') from None
        self.data = self.model.createData()
        self.axis_names = tuple(axis_names)
        self.n = len(self.axis_names)
        self._frame_w = self._frame_id(urdf_path, workpiece_frame)
        self._frame_t = self._frame_id(urdf_path, tool_frame)

        simple_axes, simple_q, circle_axes, circle_q, v_index = [], [], [], [], []
        for i, name in enumerate(self.axis_names):
            if not self.model.existJointName(name):
                raise ConfigError(f'{urdf_path}: no joint {name!r}')
            joint = self.model.joints[self.model.getJointId(name)]
            if joint.nv != 1 or joint.nq not in (1, 2):
                raise ConfigError(f'{urdf_path}: joint {name!r} is not a one-axis joint')
            (simple_axes, circle_axes)[joint.nq == 2].append(i)
            (simple_q, circle_q)[joint.nq == 2].append(joint.idx_q)
            v_index.append(joint.idx_v)
        if self.model.nv != self.n:
            raise ConfigError(f'{urdf_path}: the model has {self.model.nv} movable joints, '
                              f'the machine {self.n} axes')
        self._simple_axes, self._simple_q = np.array(simple_axes, int), np.array(simple_q, int)
        self._circle_axes, self._circle_q = np.array(circle_axes, int), np.array(circle_q, int)
        self._v_index = np.array(v_index, int)
        self._neutral = pin.neutral(self.model)

    @classmethod
    def from_config(cls, machine: MachineConfig) -> Kinematics:
        return cls(machine.urdf_path, machine.axis_names, machine.workpiece_frame, machine.tool_frame)

    def _frame_id(self, urdf_path, name: str) -> int:
        if not self.model.existFrame(name):
            raise ConfigError(f'{urdf_path}: no frame {name!r}')
        return self.model.getFrameId(name)

    def pin_configuration(self, q) -> np.ndarray:
        """Pinocchio configuration vector (length model.nq) for axis positions q (length n)."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n,):
            raise ValueError(f'expected {self.n} axis positions ({" ".join(self.axis_names)}), '
                             f'got shape {q.shape}')
        out = self._neutral.copy()
        out[self._simple_q] = q[self._simple_axes]
        angles = q[self._circle_axes]
        out[self._circle_q] = np.cos(angles)
        out[self._circle_q + 1] = np.sin(angles)
        return out

    def _placements(self) -> tuple[pin.SE3, pin.SE3]:
        return (pin.updateFramePlacement(self.model, self.data, self._frame_w),
                pin.updateFramePlacement(self.model, self.data, self._frame_t))

    def tool_pose(self, q) -> np.ndarray:
        """Homogeneous transform ^wT_t (4 x 4): tool-tip frame in the workpiece frame."""
        pin.forwardKinematics(self.model, self.data, self.pin_configuration(q))
        w, t = self._placements()
        return w.actInv(t).homogeneous

    def forward(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Tool-tip position P (m) and unit tool axis O, in the workpiece frame."""
        pin.forwardKinematics(self.model, self.data, self.pin_configuration(q))
        return self._position_orientation(*self._placements())

    @staticmethod
    def _position_orientation(w: pin.SE3, t: pin.SE3) -> tuple[np.ndarray, np.ndarray]:
        rw_t = w.rotation.T
        return rw_t @ (t.translation - w.translation), rw_t @ t.rotation[:, 2]

    def forward_and_jacobian(self, q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """P, O and the analytic 6 x n Jacobian d[P; O]/dq (thesis Eq. 3.13)."""
        pin.computeJointJacobians(self.model, self.data, self.pin_configuration(q))
        w, t = self._placements()
        jw = pin.getFrameJacobian(self.model, self.data, self._frame_w, _LWA)[:, self._v_index]
        jt = pin.getFrameJacobian(self.model, self.data, self._frame_t, _LWA)[:, self._v_index]
        rw_t = w.rotation.T
        r = t.translation - w.translation
        o = t.rotation[:, 2]
        jacobian = np.empty((6, self.n))
        jacobian[:3] = rw_t @ (jt[:3] - jw[:3] + _skew(r) @ jw[3:])
        jacobian[3:] = -rw_t @ (_skew(o) @ (jt[3:] - jw[3:]))
        return rw_t @ r, rw_t @ o, jacobian

    def jacobian(self, q) -> np.ndarray:
        return self.forward_and_jacobian(q)[2]


def orientation_basis(o: np.ndarray) -> np.ndarray:
    """3 x 2 orthonormal basis of the plane normal to the unit vector o (continuous in o away
    from the seam where o is anti-parallel to the helper axis)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(o[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(o, helper)
    e1 /= np.linalg.norm(e1)
    return np.column_stack((e1, np.cross(o, e1)))


def task_jacobian(jacobian: np.ndarray, o: np.ndarray) -> np.ndarray:
    """5 x n task Jacobian [dP/dq; B^T dO/dq], B = orientation_basis(o): the full-rank form of
    the rank-deficient 6 x n J (see the module docstring)."""
    return np.vstack((jacobian[:3], orientation_basis(o).T @ jacobian[3:]))
