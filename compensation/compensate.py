"""Geometric error compensation with the fine stage (Yuen thesis, seed
000_d9dd5f6a818770e4.txt, §5.4, Eqs. 5.14-5.27, Algorithm 2), batched over reference rows.

For each reference row q[k] the fine-stage (table) axes q_f are iterated (Eq. 5.26 with the
seed-notes.md errata: no |.| in Eq. 5.14, and the step that reduces the error is +J^c+ dP):

    dP_j    = P_i(q[k]) - P_a(q_j)                                  (Eq. 5.14)
    q_f,j+1 = q_f,j + J^c+ dP_j - (I - J^c+ J^c) beta^c grad H^c(q_f,j)   (Eqs. 5.21-5.26)

until |dP| < nu (Eq. 5.27: "converged") or `max_iterations` (the cap) is reached; the result
reports which, per row. J^c = dP_a/dq_f (3 x 6, Eq. 5.20) comes from the error-augmented
model; J^c+ = J^cT (J^c J^cT)^-1 (Eq. 5.21). H^c = sum u^2/(1-u^2), u = (q - centre)/half
stroke, over the fine axes with a stroke (trajectory/redundancy.py's cost and its exact
gradient: Eq. 5.24 is not the gradient of Eq. 5.23, as seed-notes.md notes for Eqs. 3.19/3.20; the unlimited c_f is left
out), descended (-beta^c with beta^c > 0).

Velocities and accelerations of the corrected rows: the correction c(q) = q* - q is a smooth
function of the reference position; its time derivatives come from central differences of c
at the Taylor neighbours q(t +- h) = q +- h v + h^2/2 a, each neighbour iterated exactly as
often as its row (so the three values are one smooth map; where the iteration count changes
between rows, the position steps by less than the last update, ~nu). Every row is computed
from its own q, v, a only, so a chunked stream gives bit-identical rows to a whole
trajectory.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from compensation.error_map import ErrorMap
from compensation.error_model import ErrorKinematics
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.model.reference import Reference

# assumed (nu of Eq. 5.27 is not stated, seed-notes.md): 1 pm, far below the 20 nm table
# sensors; Newton steps reach it in 2-3 iterations from micrometre errors, and a tolerance
# this far below the errors makes the correction a smooth function of q (see above).
TOLERANCE = 1e-12
# assumed: iteration cap (Algorithm 2 has none); 3 iterations suffice for um-level errors.
MAX_ITERATIONS = 10
# assumed (beta^c not stated, seed-notes.md): the nullspace step beta^c grad H^c is 4 nm per
# iteration at 10 % of the 100 um fine stroke and 1 um at 90 %; the corrections themselves are
# a few um and ~100 urad, so it only matters near the stroke ends.
BETA = 2e-12
# assumed: Taylor-neighbour spacing for the correction's velocity and acceleration; 1 ms keeps
# the rounding of c (1e-17 m) far below the differences, and the truncation (h^2 c''') is nil.
DERIVATIVE_STEP = 1e-3


@dataclass(frozen=True)
class Compensation:
    """Corrected rows and how the iteration ended for each."""
    position: np.ndarray        # (N, n) q*: the input with the fine axes corrected
    iterations: np.ndarray      # (N,) iterations run
    converged: np.ndarray       # (N,) bool: |dP| < nu reached (else the cap stopped it)
    residual: np.ndarray        # (N,) |dP| after the last iteration, m (predicted by the model)
    initial_error: np.ndarray   # (N,) |dP| of the uncorrected row, m

    def summary(self) -> dict:
        return {'rows': int(len(self.iterations)), 'converged': int(self.converged.sum()),
                'capped': int((~self.converged).sum()),
                'max_iterations': int(self.iterations.max(initial=0)),
                'max_residual': float(self.residual.max(initial=0.0)),
                'max_initial_error': float(self.initial_error.max(initial=0.0))}


class Compensator:
    """Algorithm 2 on a model (ErrorKinematics) with the machine's fine axes."""

    def __init__(self, machine: MachineConfig, model: ErrorKinematics, ideal: ErrorKinematics,
                 tolerance: float = TOLERANCE, max_iterations: int = MAX_ITERATIONS, beta: float = BETA):
        # the whole fine stage: every axis of the drive type of the dual-stage fine axes
        fine_types = {machine.axis(name).drive.type for name in machine.fine_axes}
        self.fine_axes = tuple(a.name for a in machine.axes if a.drive.type in fine_types)
        if not self.fine_axes:
            raise ConfigError(f'{machine.yaml_path}: dual_stage: no fine stage to compensate with')
        with_errors = [a for a in self.fine_axes if model.has_errors(a)]
        if with_errors:
            raise ConfigError(f'{model.error_map.source}: the compensating axes {", ".join(with_errors)} '
                              'must not carry error functions (J^c treats them as error-free)')
        self.model, self.ideal = model, ideal
        self.tolerance, self.max_iterations, self.beta = tolerance, max_iterations, beta
        self.fine_index = np.array([machine.axis_names.index(a) for a in self.fine_axes])
        strokes = [machine.axis(a).stroke for a in self.fine_axes]
        self._limited = np.array([s is not None for s in strokes])
        self._centre = np.array([0.5 * (s[0] + s[1]) if s else 0.0 for s in strokes])
        self._half = np.array([0.5 * (s[1] - s[0]) if s else 1.0 for s in strokes])

    @classmethod
    def from_map(cls, machine: MachineConfig, error_map: ErrorMap, **settings) -> Compensator:
        """The compensator of `machine` with the model `error_map` (fitted or true)."""
        kinematics = Kinematics.from_config(machine)
        return cls(machine, ErrorKinematics.from_config(machine, error_map, kinematics),
                   ErrorKinematics.from_config(machine, None, kinematics), **settings)

    def grad_h(self, q_fine: np.ndarray) -> np.ndarray:
        """Exact gradient of H^c = sum u^2/(1-u^2) over the limited fine axes (N, 6)."""
        u = np.clip((q_fine - self._centre) / self._half, -0.999, 0.999)
        return np.where(self._limited, 2.0 * u / ((1.0 - u * u) ** 2 * self._half), 0.0)

    def _step(self, q: np.ndarray, target: np.ndarray):
        """|dP| and the Eq. (5.26) update of the fine axes for rows q."""
        p_a, jc = self.model.positions_and_jacobian(q, self.fine_axes)
        dp = target - p_a
        jct = np.swapaxes(jc, 1, 2)
        pinv = jct @ np.linalg.inv(jc @ jct)                                      # Eq. (5.21)
        null = np.eye(len(self.fine_axes)) - pinv @ jc
        grad = self.grad_h(q[:, self.fine_index])
        update = (np.einsum('nij,nj->ni', pinv, dp)
                  - self.beta * np.einsum('nij,nj->ni', null, grad))             # Eq. (5.26)
        return np.linalg.norm(dp, axis=1), update

    def solve(self, q, iterations=None) -> Compensation:
        """Algorithm 2 for rows q (N, n) towards their ideal tool tips P_i(q) (Eq. 5.14).
        With `iterations` (N,) each row runs exactly that many updates instead."""
        q = np.array(q, float, ndmin=2)
        target = self.ideal.positions(q)
        count = np.zeros(len(q), int)
        converged = np.zeros(len(q), bool)
        error, update = self._step(q, target)
        initial = error.copy()
        for _ in range(self.max_iterations if iterations is None else int(iterations.max(initial=0))):
            active = (error >= self.tolerance) & (count < self.max_iterations) if iterations is None \
                else count < iterations
            converged |= (error < self.tolerance) & (count < self.max_iterations)
            if not active.any():
                break
            rows = np.flatnonzero(active)
            q[np.ix_(rows, self.fine_index)] += update[rows]
            count[rows] += 1
            error[rows], update[rows] = self._step(q[rows], target[rows])
        converged |= error < self.tolerance
        return Compensation(q, count, converged, error, initial)

    def compensate_rows(self, position, velocity, acceleration):
        """Corrected (position, velocity, acceleration) rows and the Compensation of the
        positions (module docstring: derivatives from Taylor neighbours)."""
        position, velocity, acceleration = (np.array(a, float, ndmin=2) for a in (position, velocity, acceleration))
        centre = self.solve(position)
        h = DERIVATIVE_STEP
        corrections = []
        for sign in (-1.0, 1.0):
            neighbour = position + sign * h * velocity + 0.5 * h * h * acceleration
            corrections.append(self.solve(neighbour, iterations=centre.iterations).position - neighbour)
        c_minus, c_plus = corrections
        c = centre.position - position
        return (centre.position, velocity + (c_plus - c_minus) / (2 * h),
                acceleration + (c_plus - 2 * c + c_minus) / (h * h), centre)

    def compensate(self, reference: Reference) -> tuple[Reference, Compensation]:
        """A whole planned trajectory, Reference in -> compensated Reference out."""
        p, v, a, comp = self.compensate_rows(reference.position, reference.velocity, reference.acceleration)
        return Reference(reference.axis_names, reference.period, p, v, a), comp
