"""A machine's kinematic chains as numpy over many configurations at once.

The chain from the base to a frame is read from the Pinocchio model of
:class:`machine_ctrl.model.kinematics.Kinematics` (joint placements, joint types and axes,
the frame's placement), so there is one definition of the machine. Each joint contributes

    placement_j  motion_j(q_j)

with motion_j a translation along, or a rotation about, one coordinate axis (the joints of
our machines: Pinocchio's PX/PY/PZ, RX/RY/RZ and the continuous RUBX/RUBY/RUBZ). :func:`walk`
composes it for every row of Q (N x n) with a few array operations per joint, not N
Pinocchio calls; a caller may add a per-joint term after each motion (`after`: the geometric
errors of compensation/error_model.py, Yuen Eq. 5.3) and tilt a prismatic joint's direction
of motion (:attr:`ChainJoint.motion`: a squareness error). Used by Kinematics.forward_many
and compensation.error_model.ErrorKinematics; equal to Pinocchio's kinematics within
rounding (tested, <= 1e-15 m).
"""
from __future__ import annotations

import numpy as np

from machine_ctrl.model.errors import ConfigError

_AXES = {'X': 0, 'Y': 1, 'Z': 2}


class ChainJoint:
    """One joint of a chain: constant placement, motion along/about a unit axis (`axis`);
    `motion` is the direction a prismatic joint moves along (the axis unless a caller tilts
    it before :meth:`freeze`)."""

    def __init__(self, name: str, index: int, prismatic: bool, axis: np.ndarray, placement):
        self.name, self.index, self.prismatic = name, index, prismatic
        self.axis = axis
        self.motion = axis
        self.rotation, self.translation = placement.rotation.copy(), placement.translation.copy()

    def freeze(self) -> None:
        """Precompute what every walk uses, once `motion` is set."""
        self.turns = bool((self.rotation != np.eye(3)).any())
        self.translation_terms = terms(self.translation)
        self.axis_terms = terms(self.axis)
        self.motion_terms = terms(self.motion)


def joint_kind(shortname: str, model_name: str) -> tuple[bool, np.ndarray]:
    """(prismatic?, unit axis) of an axis-aligned Pinocchio joint model; ConfigError else."""
    for prefix, prismatic in (('JointModelP', True), ('JointModelRUB', False), ('JointModelR', False)):
        rest = shortname[len(prefix):]
        if shortname.startswith(prefix) and rest in _AXES:
            axis = np.zeros(3)
            axis[_AXES[rest]] = 1.0
            return prismatic, axis
    raise ConfigError(f'joint {model_name!r}: {shortname} is not supported by the batched kinematics '
                      '(axis-aligned prismatic/revolute joints only)')


def chain(model, axis_names, frame_name: str) -> tuple[list[ChainJoint], object]:
    """The joints from the base to the frame `frame_name` of a Pinocchio `model` (in that
    order; `axis_names`: the machine's, for each joint's column of Q), and the frame's
    placement on its joint. ConfigError for a joint that is not axis-aligned."""
    frame = model.frames[model.getFrameId(frame_name)]
    ids, j = [], frame.parentJoint
    while j > 0:
        ids.append(j)
        j = model.parents[j]
    joints = []
    for j in reversed(ids):
        name = model.names[j]
        prismatic, axis = joint_kind(model.joints[j].shortname(), name)
        joints.append(ChainJoint(name, list(axis_names).index(name), prismatic, axis, model.jointPlacements[j]))
    return joints, frame.placement


def end_frame(placement) -> tuple[np.ndarray, tuple]:
    """A frame's placement as :func:`walk` takes it."""
    return placement.rotation.copy(), terms(placement.translation)


def rotate(rot: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """rot @ (rotation by `angle` about the coordinate axis `axis`), (N, 3, 3): only two
    columns change (the product with Pinocchio's exact cos/sin matrix, without the zeros)."""
    i = int(np.argmax(axis))
    a, b = (i + 1) % 3, (i + 2) % 3
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    out = rot.copy()
    out[:, :, a] = rot[:, :, a] * c + rot[:, :, b] * s
    out[:, :, b] = rot[:, :, b] * c - rot[:, :, a] * s
    return out


def terms(vector: np.ndarray) -> tuple[tuple[int, float], ...]:
    """The non-zero components (index, value) of a constant vector."""
    return tuple((int(k), float(vector[k])) for k in np.flatnonzero(vector))


def apply(rot: np.ndarray, vector_terms) -> np.ndarray:
    """rot @ vector for a constant vector given by its terms, summing only those."""
    out = np.zeros(rot.shape[:2])
    for k, value in vector_terms:
        out += rot[:, :, k] * value
    return out


def walk(joints, frame, q: np.ndarray, want=(), after=None):
    """Base pose (R (N, 3, 3), p (N, 3)) of the chain's end frame (`frame`: from
    :func:`end_frame`) for the rows of q; for the axes named in `want` also the base
    direction and origin of the joint axis (for a Jacobian). `after(joint, q_j, R, p)`, if
    given, returns (R, p) after each joint's motion (an error term)."""
    n = q.shape[0]
    rot = np.broadcast_to(np.eye(3), (n, 3, 3))
    pos = np.zeros((n, 3))
    axes = {}
    for j in joints:
        pos = pos + apply(rot, j.translation_terms)
        if j.turns:
            rot = rot @ j.rotation
        qj = q[:, j.index]
        if j.name in want:
            axes[j.name] = (apply(rot, j.axis_terms), pos)
        if j.prismatic:
            pos = pos + apply(rot, j.motion_terms) * qj[:, None]
        else:
            rot = rotate(rot, j.axis, qj)
        if after is not None:
            rot, pos = after(j, qj, rot, pos)
    frame_rotation, frame_terms = frame
    return rot @ frame_rotation, pos + apply(rot, frame_terms), axes


def packed(chains) -> tuple:
    """Chains (each (joints, end_frame(...)) as Kinematics keeps them) as flat arrays, for
    compiled code that walks them (trajectory/resolved_rate.py): per joint, over the chains
    one after another, the placement rotation (J, 3, 3) and translation (J, 3), prismatic
    (J,) bool, coordinate axis 0/1/2 (J,), column of q (J,) and chain number (J,); per chain,
    the end frame's rotation (C, 3, 3) and translation (C, 3). A tilted motion (a caller's
    error term) is not represented: only :attr:`ChainJoint.motion` == axis chains pack."""
    joints = [(c, j) for c, (chain_joints, _) in enumerate(chains) for j in chain_joints]
    if any(j.motion is not j.axis for _, j in joints):
        raise ValueError('a chain with a tilted motion does not pack')
    frames = [frame for _, frame in chains]
    frame_translation = np.zeros((len(frames), 3))
    for c, (_, frame_terms) in enumerate(frames):
        for k, value in frame_terms:
            frame_translation[c, k] = value
    return (np.array([j.rotation for _, j in joints]).reshape(-1, 3, 3),
            np.array([j.translation for _, j in joints]).reshape(-1, 3),
            np.array([j.prismatic for _, j in joints], dtype=np.bool_),
            np.array([int(np.argmax(j.axis)) for _, j in joints], dtype=np.int64),
            np.array([j.index for _, j in joints], dtype=np.int64),
            np.array([c for c, _ in joints], dtype=np.int64),
            np.array([rotation for rotation, _ in frames]).reshape(-1, 3, 3),
            frame_translation)
