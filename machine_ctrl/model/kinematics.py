"""Forward kinematics and Jacobian of any machine, built with Pinocchio from its URDF.

A machine is two kinematic chains from one base frame: the workpiece chain ending in the
workpiece frame and the tool chain ending in the tool-tip frame (Yuen thesis Eqs. 3.1-3.2).
In the workpiece frame (thesis Eqs. 3.4-3.5):

    ^wT_t(q) = (^BT_w)^-1 ^BT_t,   P(q) = tool-tip position,   O(q) = ^wR_t e_z (tool axis)

The analytic Jacobian J = d[P; O]/dq (thesis Eq. 3.13, 6 x n) is composed from Pinocchio's
spatial (WORLD) Jacobians of the two frames: their difference is the twist of the tool
relative to the workpiece. Seen at the tool tip with workpiece axes (adjoint of the frame
(R_w, p_t)) its linear part is the velocity of the tip relative to the workpiece, i.e.
dP/dq, and its angular part omega_rel gives dO/dq = omega_rel x O.

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

import math
from pathlib import Path

import numpy as np
import pinocchio as pin

from machine_ctrl.model.chain import chain, end_frame, packed, walk
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.errors import ConfigError

_WORLD = pin.ReferenceFrame.WORLD


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

        # Pinocchio q[k] = extended[gather[k]], extended = [q..., cos c1, sin c1, cos c2, ...]
        gather, circle_axes, v_index = np.full(self.model.nq, -1), [], []
        for i, name in enumerate(self.axis_names):
            if not self.model.existJointName(name):
                raise ConfigError(f'{urdf_path}: no joint {name!r}')
            joint = self.model.joints[self.model.getJointId(name)]
            if joint.nv != 1 or joint.nq not in (1, 2):
                raise ConfigError(f'{urdf_path}: joint {name!r} is not a one-axis joint')
            if joint.nq == 1:
                gather[joint.idx_q] = i
            else:
                slot = self.n + 2 * len(circle_axes)
                gather[joint.idx_q:joint.idx_q + 2] = slot, slot + 1
                circle_axes.append(i)
            v_index.append(joint.idx_v)
        if self.model.nv != self.n or (gather < 0).any():
            raise ConfigError(f'{urdf_path}: the model has {self.model.nv} movable joints, '
                              f'the machine {self.n} axes')
        self._gather, self._circle_axes = gather, tuple(circle_axes)
        self._v_index = np.array(v_index, int)
        # the configuration filled in place (no list round trip per call): the slots of the
        # one-value joints and their axes, and (axis, cos slot, sin slot) of each circle joint
        self._linear_slots = np.flatnonzero(gather < self.n)
        self._linear_axes = gather[self._linear_slots]
        self._circle_slots = tuple((i, int(np.flatnonzero(gather == self.n + 2 * j)[0]),
                                    int(np.flatnonzero(gather == self.n + 2 * j + 1)[0]))
                                   for j, i in enumerate(circle_axes))
        self._configuration_buffer = np.zeros(self.model.nq)
        try:                 # the two chains as forward_many walks them (None: a joint it does not take)
            self._chains = tuple(self._walked(frame) for frame in (workpiece_frame, tool_frame))
        except ConfigError:
            self._chains = None
        self._packed = None if self._chains is None else packed(self._chains)

    def _walked(self, frame: str):
        joints, placement = chain(self.model, self.axis_names, frame)
        for joint in joints:
            joint.freeze()
        return joints, end_frame(placement)

    def forward_many(self, q) -> tuple[np.ndarray, np.ndarray]:
        """P and O (m x 3 each) of m configurations (the rows of q, m x n) at once: the two
        chains walked with numpy over every row (machine_ctrl/model/chain.py), so a chunk of
        rows costs a few numpy calls per joint instead of a Pinocchio call per row. Equal to
        :meth:`forward` within rounding (1e-15 m / rad on our machines, tested); a machine
        with a joint the walk does not take gets :meth:`forward` row by row."""
        q = np.asarray(q, dtype=float)
        q = q[None] if q.ndim == 1 else q
        if q.ndim != 2 or q.shape[1] != self.n:
            raise ValueError(f'expected rows of {self.n} axis positions ({" ".join(self.axis_names)}), '
                             f'got shape {q.shape}')
        if self._chains is None:
            rows = [self.forward(row) for row in q]
            return np.array([p for p, _ in rows]).reshape(-1, 3), np.array([o for _, o in rows]).reshape(-1, 3)
        (w_joints, w_frame), (t_joints, t_frame) = self._chains
        w_rotation, w_position, _ = walk(w_joints, w_frame, q)
        t_rotation, t_position, _ = walk(t_joints, t_frame, q)
        # ^wT_t = (^BT_w)^-1 ^BT_t: P = R_w^T (p_t - p_w), O = R_w^T R_t e_z
        inverse = np.swapaxes(w_rotation, 1, 2)
        return (np.einsum('nij,nj->ni', inverse, t_position - w_position),
                np.einsum('nij,nj->ni', inverse, t_rotation[:, :, 2]))

    def packed_chains(self) -> tuple | None:
        """The workpiece chain (number 0) and the tool chain (1) as flat arrays for compiled
        code (:func:`machine_ctrl.model.chain.packed`); None for a machine with a joint the
        batched walk does not take."""
        return self._packed

    @classmethod
    def from_config(cls, machine: MachineConfig) -> Kinematics:
        return cls(machine.urdf_path, machine.axis_names, machine.workpiece_frame, machine.tool_frame)

    def _frame_id(self, urdf_path, name: str) -> int:
        if not self.model.existFrame(name):
            raise ConfigError(f'{urdf_path}: no frame {name!r}')
        return self.model.getFrameId(name)

    def pin_configuration(self, q) -> np.ndarray:
        """Pinocchio configuration vector (length model.nq) for axis positions q (length n)."""
        return self._configuration(q).copy()

    def _configuration(self, q) -> np.ndarray:
        """pin_configuration in the kinematics' own buffer (overwritten by the next call):
        for the Pinocchio calls of forward and forward_and_jacobian, which read it at once."""
        values = np.asarray(q, dtype=float)
        if values.shape != (self.n,):
            raise ValueError(f'expected {self.n} axis positions ({" ".join(self.axis_names)}), '
                             f'got shape {values.shape}')
        buffer = self._configuration_buffer
        buffer[self._linear_slots] = values[self._linear_axes]
        for axis, cos_slot, sin_slot in self._circle_slots:
            angle = float(values[axis])
            buffer[cos_slot], buffer[sin_slot] = math.cos(angle), math.sin(angle)
        return buffer

    def _placements(self) -> tuple[pin.SE3, pin.SE3]:
        return (pin.updateFramePlacement(self.model, self.data, self._frame_w),
                pin.updateFramePlacement(self.model, self.data, self._frame_t))

    def tool_pose(self, q) -> np.ndarray:
        """Homogeneous transform ^wT_t (4 x 4): tool-tip frame in the workpiece frame."""
        pin.forwardKinematics(self.model, self.data, self._configuration(q))
        w, t = self._placements()
        return w.actInv(t).homogeneous

    def forward(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Tool-tip position P (m) and unit tool axis O, in the workpiece frame."""
        pin.forwardKinematics(self.model, self.data, self._configuration(q))
        w, t = self._placements()
        pose = w.actInv(t)
        return pose.translation, pose.rotation[:, 2]

    def forward_and_jacobian(self, q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """P, O and the analytic 6 x n Jacobian d[P; O]/dq (thesis Eq. 3.13)."""
        pin.computeJointJacobians(self.model, self.data, self._configuration(q))
        w, t = self._placements()
        relative = (pin.getFrameJacobian(self.model, self.data, self._frame_t, _WORLD)
                    - pin.getFrameJacobian(self.model, self.data, self._frame_w, _WORLD))
        # relative twist seen at the tool tip, in workpiece axes: [dP/dq; omega_rel]
        jacobian = pin.SE3(w.rotation, t.translation).actionInverse @ relative
        pose = w.actInv(t)
        o = pose.rotation[:, 2]
        jacobian[3:] = pin.skew(-o) @ jacobian[3:]          # dO = omega_rel x O
        return pose.translation, o, jacobian[:, self._v_index]

    def jacobian(self, q) -> np.ndarray:
        return self.forward_and_jacobian(q)[2]


def orientation_basis(o: np.ndarray) -> np.ndarray:
    """3 x 2 orthonormal basis of the plane normal to the unit vector o (continuous in o except
    across the cone |o_x| = 0.9, where the helper axis switches from x to y)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(o[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(o, helper)
    e1 /= np.linalg.norm(e1)
    return np.column_stack((e1, np.cross(o, e1)))


def task_jacobian(jacobian: np.ndarray, o: np.ndarray) -> np.ndarray:
    """5 x n task Jacobian [dP/dq; B^T dO/dq], B = orientation_basis(o): the full-rank form of
    the rank-deficient 6 x n J (see the module docstring)."""
    return np.vstack((jacobian[:3], orientation_basis(o).T @ jacobian[3:]))
