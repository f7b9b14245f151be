"""A stage described by its modes: the continuous state space of

    G(s) = prod_i w_i^2 / (s^2 + 2 zeta_i w_i s + w_i^2)  [x p / (s + p)]     (unit static gain)

a cascade of the real pole (when there is one) and the modes, each stage's output the next
one's input, the last stage's position the output. Sörnmo's piezo micro manipulator axes
(seed 004, section 2.3: orders 4 / 2 / 5) are of this form; the simulated plant
(hw_sim/piezo_stage.py) and the LQG law's model (machine_ctrl/control/lqg.py) build it here.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import expm


def state_space(modes, real_pole: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C) of G(s) for `modes` ((omega rad/s, zeta), ...) and `real_pole` (rad/s, or
    None / 0 for none)."""
    real_pole = real_pole or None
    n = 2 * len(modes) + (real_pole is not None)
    a, b, c = np.zeros((n, n)), np.zeros(n), np.zeros(n)
    stages = []                      # (row of the stage's input, its gain, the stage's output state)
    if real_pole is not None:        # x' = p (in - x)
        a[0, 0] = -real_pole
        stages.append((0, real_pole, 0))
    for k, (w, zeta) in enumerate(modes):    # x'' = w^2 (in - x) - 2 zeta w x'
        i = 2 * k + (real_pole is not None)
        a[i, i + 1], a[i + 1, i], a[i + 1, i + 1] = 1.0, -w * w, -2 * zeta * w
        stages.append((i + 1, w * w, i))
    b[stages[0][0]] = stages[0][1]
    for (_, _, previous), (row, gain, _) in zip(stages, stages[1:]):
        a[row, previous] += gain
    c[stages[-1][2]] = 1.0
    return a, b, c


def held(a: np.ndarray, b: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Gamma): the exact zero-order-hold discretization of x' = A x + B u at `period`."""
    n = len(b)
    augmented = np.zeros((n + 1, n + 1))
    augmented[:n, :n], augmented[:n, n] = a, b
    discrete = expm(augmented * period)
    return discrete[:n, :n], discrete[:n, n]
