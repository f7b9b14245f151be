"""H2-optimal output feedback for a generalized plant, by the two algebraic Riccati
equations of Doyle, Glover, Khargonekar and Francis (Zhou, Doyle and Glover, "Robust and
Optimal Control", 1996, Ch. 14; what MATLAB's ``h2syn``, cited by seed
003_edeaa855566124b7 section 6.2, solves). Plain numbers in, a result out, scipy only.

The generalized plant (Ding Fig. 6-1), continuous time:

    x' = A x  + B1 w  + B2 u
    z  = C1 x         + D12 u            (D11 = 0: otherwise the H2 norm is infinite)
    y  = C2 x + D21 w                    (D22 = 0)

w: unit-intensity white noise (the disturbances' shaping filters are part of A), z: the
weighted errors, y: the measurement, u: the command. The controller u = K(s) y minimizing
the H2 norm of w -> z (Eqs. 6-1, 6-2) is

    X: A'X + XA - (XB2 + C1'D12) R1^-1 (B2'X + D12'C1) + C1'C1 = 0,   R1 = D12'D12
    Y: AY + YA' - (YC2' + B1D21') R2^-1 (C2Y + D21B1') + B1B1' = 0,   R2 = D21D21'
    F = -R1^-1 (B2'X + D12'C1),   L = -(YC2' + B1D21') R2^-1
    K(s):  x_K' = (A + B2 F + L C2) x_K - L y,   u = F x_K

with X, Y the stabilizing solutions. They exist when (A, B2) is stabilizable, (C2, A)
detectable, R1 and R2 are nonsingular and neither A - B2 R1^-1 D12'C1 (with C1) nor
A - B1 D21' R2^-1 C2 (with B1) has an uncontrollable or unobservable mode on the imaginary
axis; a shaping filter with a pole at s = 0 breaks the first condition (nothing can steer
it), which is why a design moves such poles slightly into the left half plane.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from scipy import linalg


class H2Status(enum.StrEnum):
    OK = 'ok'
    INVALID_INPUT = 'invalid_input'          # shapes, non-finite numbers, D11 or D22 not zero
    SINGULAR = 'singular'                    # D12 without full column rank or D21 without full row rank
    NO_SOLUTION = 'no_solution'              # a Riccati equation has no stabilizing solution


@dataclass(frozen=True)
class GeneralizedPlant:
    """The module doc's plant; arrays 2-D, SI units of the problem."""
    a: np.ndarray
    b1: np.ndarray
    b2: np.ndarray
    c1: np.ndarray
    c2: np.ndarray
    d12: np.ndarray
    d21: np.ndarray
    d11: np.ndarray | None = None     # None: zero
    d22: np.ndarray | None = None     # None: zero


@dataclass(frozen=True)
class StateSpace:
    """x' = a x + b u, y = c x + d u (continuous) or x_{k+1} = a x_k + b u_k (discrete)."""
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray


@dataclass(frozen=True)
class H2Result:
    status: H2Status
    reason: str                                # '' when ok
    controller: StateSpace | None = None       # u = K y
    norm: float = float('nan')                 # H2 norm of the closed loop w -> z

    @property
    def ok(self) -> bool:
        return self.status is H2Status.OK


def _shape_problem(p: GeneralizedPlant) -> str | None:
    n = p.a.shape[0] if p.a.ndim == 2 else -1
    if n < 1 or p.a.shape != (n, n):
        return f'A must be square, got shape {p.a.shape}'
    nw, nu, nz, ny = p.b1.shape[1], p.b2.shape[1], p.c1.shape[0], p.c2.shape[0]
    expected = {'b1': (n, nw), 'b2': (n, nu), 'c1': (nz, n), 'c2': (ny, n), 'd12': (nz, nu), 'd21': (ny, nw)}
    for name, shape in expected.items():
        if getattr(p, name).shape != shape:
            return f'{name.upper()} must have shape {shape}, got {getattr(p, name).shape}'
    for name in ('a', 'b1', 'b2', 'c1', 'c2', 'd12', 'd21'):
        if not np.all(np.isfinite(getattr(p, name))):
            return f'{name.upper()} has a non-finite entry'
    for name in ('d11', 'd22'):
        m = getattr(p, name)
        if m is not None and np.any(m != 0):
            return f'{name.upper()} must be zero (module doc)'
    return None


def closed_loop(p: GeneralizedPlant, k: StateSpace) -> StateSpace:
    """w -> z with u = K y (D22 = 0): states [plant, controller]."""
    a = np.block([[p.a + p.b2 @ k.d @ p.c2, p.b2 @ k.c], [k.b @ p.c2, k.a]])
    b = np.vstack([p.b1 + p.b2 @ k.d @ p.d21, k.b @ p.d21])
    c = np.hstack([p.c1 + p.d12 @ k.d @ p.c2, p.d12 @ k.c])
    return StateSpace(a, b, c, p.d12 @ k.d @ p.d21)


def h2_norm(sys: StateSpace) -> float:
    """H2 norm of a stable, strictly proper continuous system: sqrt(trace(C P C')) with
    A P + P A' + B B' = 0; inf when unstable or not strictly proper."""
    if np.any(sys.d != 0) or np.max(np.linalg.eigvals(sys.a).real) >= 0:
        return float('inf')
    _, (sc, _) = linalg.matrix_balance(sys.a, permute=False, separate=True)     # a diagonal similarity
    a, b, c = sys.a * sc / sc[:, None], sys.b / sc[:, None], sys.c * sc
    p = linalg.solve_continuous_lyapunov(a, -b @ b.T)
    return float(np.sqrt(max(np.trace(c @ p @ c.T), 0.0)))


def h2_synthesis(plant: GeneralizedPlant) -> H2Result:
    """The H2-optimal controller of `plant` (module doc), or the reason there is none."""
    problem = _shape_problem(plant)
    if problem:
        return H2Result(H2Status.INVALID_INPUT, problem)
    a, b1, b2, c1, c2, d12, d21 = plant.a, plant.b1, plant.b2, plant.c1, plant.c2, plant.d12, plant.d21
    r1, r2 = d12.T @ d12, d21 @ d21.T
    if np.linalg.matrix_rank(d12) < d12.shape[1]:
        return H2Result(H2Status.SINGULAR, 'D12 must have full column rank: every command needs a cost')
    if np.linalg.matrix_rank(d21) < d21.shape[0]:
        return H2Result(H2Status.SINGULAR, 'D21 must have full row rank: every measurement needs a noise')
    try:
        x = linalg.solve_continuous_are(a, b2, c1.T @ c1, r1, s=c1.T @ d12)
        y = linalg.solve_continuous_are(a.T, c2.T, b1 @ b1.T, r2, s=b1 @ d21.T)
    except (np.linalg.LinAlgError, ValueError) as exc:
        return H2Result(H2Status.NO_SOLUTION, f'no stabilizing Riccati solution ({exc}); is every shaping '
                                              'filter pole in the open left half plane?')
    f = -np.linalg.solve(r1, b2.T @ x + d12.T @ c1)
    gain = -np.linalg.solve(r2, (y @ c2.T + b1 @ d21.T).T).T
    k = StateSpace(a + b2 @ f + gain @ c2, -gain, f, np.zeros((b2.shape[1], c2.shape[0])))
    norm = h2_norm(closed_loop(plant, k))
    if not np.isfinite(norm):
        return H2Result(H2Status.NO_SOLUTION, 'the Riccati solutions do not stabilize the loop (numerically '
                                              'ill-posed plant: check the scaling of its weights)')
    return H2Result(H2Status.OK, '', k, norm)
