"""Algorithm 1's inner loop compiled: the resolved rate of Eq. 3.27 integrated by RK4 (Eq.
3.24) with the Newton projection after each step, the kinematics walked along the machine's
two chains (Yuen thesis Eqs. 3.1-3.5, 3.13), all in one numba function.

The same algorithm as the Python loop of :func:`trajectory.redundancy.resolve` (its
docstring has the method, the errata and the settings); only where the numbers come from
differs:

* P, O and J = d[P; O]/dq from the chains of :func:`machine_ctrl.model.chain.packed`, not
  from Pinocchio: each chain walked from the base, joint by joint (placement, then the
  motion along or about a coordinate axis), and J's column of axis i composed from that
  joint's base axis a_i and origin r_i, as the relative twist of the tool seen at the tool
  tip in workpiece axes (module docstring of machine_ctrl/model/kinematics.py)::

      dP/dq_i = ±R_w^T a_i (prismatic),  ±R_w^T (a_i x (p_t - r_i)) (revolute)
      dO/dq_i = 0 (prismatic),           (±R_w^T a_i) x O (revolute)

  with + for a joint of the tool chain and - for one of the workpiece chain (a joint of
  both cancels);
* small matrix products written out as loops summed in index order, and the chain walk in
  place scalar by scalar (numba's ``@`` calls BLAS, whose per-call cost was most of a 3 x 3
  product's: P, O and J took 8.7 µs a call with it, 1.0 µs without, on the micromill);
  LAPACK for the 5 x 5 determinant and inverse and the SVD of a rank-deficient task.

So the configurations differ from the Python loop's by rounding, grown along the path by
the integration (tested against it: test/test_resolved_rate.py). Compiled once per
installation (numba's cache in the package's ``__pycache__``); a process's first call loads
it (:func:`warm` does so ahead).

Why compiled: per RK4 step the Python loop makes ~60 numpy calls on 3- to 9-vectors and
five Pinocchio calls with their conversions, ~300 µs of interpreter overhead against a few
µs of arithmetic (issue [5/8]'s profile; bench/RESULTS.md).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_CACHE = True          # numba's on-disk cache: compiled once, loaded by later processes


@njit(cache=_CACHE)
def _mm(a, b):
    """a @ b for small matrices, summed in index order (no BLAS call: its per-call cost is
    most of a 3 x 3 product's, and its kernels may fuse multiply-adds)."""
    out = np.empty((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            total = 0.0
            for k in range(a.shape[1]):
                total += a[i, k] * b[k, j]
            out[i, j] = total
    return out


@njit(cache=_CACHE)
def _mv(a, v):
    """a @ v (matrix times vector), as :func:`_mm`."""
    out = np.empty(a.shape[0])
    for i in range(a.shape[0]):
        total = 0.0
        for k in range(a.shape[1]):
            total += a[i, k] * v[k]
        out[i] = total
    return out


@njit(cache=_CACHE)
def _dot(a, b):
    total = 0.0
    for k in range(len(a)):
        total += a[k] * b[k]
    return total


@njit(cache=_CACHE)
def _walk(chains, c, q, axis_out, origin_out):
    """Base rotation and position of chain c's end frame at q; each joint's base axis and
    origin into axis_out / origin_out (rows of the packed joint order). In place, scalar by
    scalar: a joint's placement (p += R t, R = R R_j), then its motion along or about its
    coordinate axis k (p += q a_k, or R's other two columns turned by q)."""
    rot, trans, prismatic, axis, column, chain_of, frame_rot, frame_trans = chains
    r = np.eye(3)
    p = np.zeros(3)
    for j in range(len(chain_of)):
        if chain_of[j] != c:
            continue
        t, placement = trans[j], rot[j]
        for i in range(3):
            p[i] += r[i, 0] * t[0] + r[i, 1] * t[1] + r[i, 2] * t[2]
        for i in range(3):
            x0, x1, x2 = r[i, 0], r[i, 1], r[i, 2]
            for m in range(3):
                r[i, m] = x0 * placement[0, m] + x1 * placement[1, m] + x2 * placement[2, m]
        k = axis[j]
        value = q[column[j]]
        for i in range(3):
            axis_out[j, i] = r[i, k]
            origin_out[j, i] = p[i]
        if prismatic[j]:
            for i in range(3):
                p[i] += r[i, k] * value
        else:
            i1, i2 = (k + 1) % 3, (k + 2) % 3
            cv, sv = math.cos(value), math.sin(value)
            for i in range(3):
                x, y = r[i, i1], r[i, i2]
                r[i, i1] = x * cv + y * sv
                r[i, i2] = y * cv - x * sv
    return _mm(r, frame_rot[c]), p + _mv(r, frame_trans[c])


@njit(cache=_CACHE)
def _cross(a, b):
    return np.array((a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]))


@njit(cache=_CACHE)
def _cross3(a0, a1, a2, b0, b1, b2):
    """a x b of scalars, as a tuple (no array made)."""
    return (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)


@njit(cache=_CACHE)
def _transposed_times(r, x0, x1, x2):
    """R^T x of a 3 x 3 R and scalars, as a tuple (no array made)."""
    return (r[0, 0] * x0 + r[1, 0] * x1 + r[2, 0] * x2,
            r[0, 1] * x0 + r[1, 1] * x1 + r[2, 1] * x2,
            r[0, 2] * x0 + r[1, 2] * x1 + r[2, 2] * x2)


@njit(cache=_CACHE)
def pose_jacobian(chains, q):
    """P, O (workpiece frame) and the 6 x n Jacobian d[P; O]/dq at q (module docstring)."""
    n_joints = len(chains[5])
    axes, origins = np.empty((n_joints, 3)), np.empty((n_joints, 3))
    r_w, p_w = _walk(chains, 0, q, axes, origins)
    r_t, p_t = _walk(chains, 1, q, axes, origins)
    position = _mv(r_w.T, p_t - p_w)          # in workpiece axes: R_w^T (...)
    o = _mv(r_w.T, r_t[:, 2])
    jac = np.zeros((6, len(q)))
    prismatic, column, chain_of = chains[2], chains[4], chains[5]
    for j in range(n_joints):
        sign = 1.0 if chain_of[j] == 1 else -1.0
        ax, ay, az = axes[j, 0], axes[j, 1], axes[j, 2]
        a = _transposed_times(r_w, ax, ay, az)
        i = column[j]
        if prismatic[j]:
            for m in range(3):
                jac[m, i] += sign * a[m]
        else:
            c = _cross3(ax, ay, az, p_t[0] - origins[j, 0], p_t[1] - origins[j, 1], p_t[2] - origins[j, 2])
            v = _transposed_times(r_w, c[0], c[1], c[2])
            w = _cross3(a[0], a[1], a[2], o[0], o[1], o[2])
            for m in range(3):
                jac[m, i] += sign * v[m]
                jac[3 + m, i] += sign * w[m]
    return position, o, jac


@njit(cache=_CACHE)
def _basis(o):
    """The orientation basis of trajectory.redundancy._basis (the same formulas)."""
    ox, oy, oz = o[0], o[1], o[2]
    if abs(ox) < 0.9:
        a, b, c = 0.0, oz, -oy
    else:
        a, b, c = -oz, 0.0, ox
    norm = math.sqrt(a * a + b * b + c * c)
    a, b, c = a / norm, b / norm, c / norm
    out = np.empty((3, 2))
    out[0, 0], out[1, 0], out[2, 0] = a, b, c
    out[0, 1], out[1, 1], out[2, 1] = oy * c - oz * b, oz * a - ox * c, ox * b - oy * a
    return out


@njit(cache=_CACHE)
def _angle(a, b):
    c = _cross(a, b)
    return math.atan2(math.sqrt(_dot(c, c)), _dot(a, b))


@njit(cache=_CACHE)
def _task(chains, active, q):
    """P, O, B and the 5 x m task Jacobian J_t over the active axes (trajectory.redundancy)."""
    p, o, jac = pose_jacobian(chains, q)
    b = _basis(o)
    jt = np.empty((5, len(active)))
    for k in range(len(active)):
        column = jac[:, active[k]]
        jt[0, k], jt[1, k], jt[2, k] = column[0], column[1], column[2]
        jt[3, k] = b[0, 0] * column[3] + b[1, 0] * column[4] + b[2, 0] * column[5]
        jt[4, k] = b[0, 1] * column[3] + b[1, 1] * column[4] + b[2, 1] * column[5]
    return p, o, b, jt


@njit(cache=_CACHE)
def _damped_inverse(jt, rank, w0, damping_max):
    """J_t^# of Eq. 3.21 with mu of Eq. 3.22 (as _Resolver.damped_inverse)."""
    if rank == 5:
        a = _mm(jt, jt.T)
        w = math.sqrt(max(np.linalg.det(a), 0.0))
        if w < w0:
            for i in range(5):
                a[i, i] += damping_max * (1.0 - w / w0) ** 2
        return _mm(jt.T, np.linalg.inv(a))
    u, sig, vt = np.linalg.svd(jt, full_matrices=False)
    sig = sig[:rank]
    w = 1.0
    for value in sig:
        w *= value
    mu = damping_max * (1.0 - w / w0) ** 2 if w < w0 else 0.0
    return _mm(vt[:rank].T * (sig / (sig * sig + mu)), u[:, :rank].T)


@njit(cache=_CACHE)
def _task_rate(pd_dot, od_dot, b):
    out = np.empty(5)
    out[:3] = pd_dot
    out[3] = b[0, 0] * od_dot[0] + b[1, 0] * od_dot[1] + b[2, 0] * od_dot[2]
    out[4] = b[0, 1] * od_dot[0] + b[1, 1] * od_dot[1] + b[2, 1] * od_dot[2]
    return out


@njit(cache=_CACHE)
def _rate(chains, active, stroke, gains, rank, target, j, q, task):
    """(g, g0) of Eq. 3.27 at target row j from q, with task = _task(q) (as _Resolver.rate)."""
    p, o, b, jt = task
    positions, axes, position_rates, axis_rates = target
    limited, centre, half = stroke
    beta, drift_gain, w0, damping_max = gains
    jsharp = _damped_inverse(jt, rank, w0, damping_max)
    dqa = _mv(jsharp, _task_rate(position_rates[j], axis_rates[j], b))
    if beta:
        grad = np.zeros(len(active))
        for m in range(len(limited)):
            u = (q[active[limited[m]]] - centre[m]) / half[m]
            u = min(max(u, -1.0 + 1e-9), 1.0 - 1e-9)
            grad[limited[m]] = 2.0 * u / (half[m] * (1.0 - u * u) ** 2)
        dqa -= beta * (grad - _mv(jsharp, _mv(jt, grad)))
    g0 = np.zeros(len(q))
    g = np.zeros(len(q))
    drift = (_mv(jsharp, drift_gain * _task_rate(positions[j] - p, axes[j] - o, b)) if drift_gain
             else np.zeros(len(active)))
    for k in range(len(active)):
        g0[active[k]] = dqa[k]
        g[active[k]] = dqa[k] + drift[k]
    return g, g0


@njit(cache=_CACHE)
def _project(chains, active, gains, rank, target, j, q, iterations, tolerance):
    """Newton iterations q += J_t^# e_t towards target row j (as _Resolver.project, not
    weighted): q, position error, orientation error and the task at q."""
    positions, axes = target[0], target[1]
    q = q.copy()
    task = _task(chains, active, q)
    ep = eo = 0.0
    for it in range(iterations + 1):
        p, o, b, jt = task
        d = positions[j] - p
        ep, eo = math.sqrt(_dot(d, d)), _angle(o, axes[j])
        if (ep <= tolerance and eo <= tolerance) or it == iterations:
            break
        step = _mv(_damped_inverse(jt, rank, gains[2], gains[3]), _task_rate(d, axes[j] - o, b))
        for k in range(len(active)):
            q[active[k]] += step[k]
        task = _task(chains, active, q)
    return q, ep, eo, task


@njit(cache=_CACHE)
def _blown_up(qs, dq, k):
    """Rows k + 1 on of NaN: what the interpreted loop holds once a rate is not finite
    (numpy carries NaN and inf through where LAPACK here refuses them), for resolve's
    non-finite rule to name the breakdown the same way."""
    qs[k + 1:] = np.nan
    dq[k + 1:] = np.nan


@njit(cache=_CACHE)
def _finite(v):
    return np.isfinite(v).all()


@njit(cache=_CACHE)
def integrate(chains, active, stroke, gains, rank, iterations, tolerance, target, ds, q, qs, dq, progress):
    """Algorithm 1 from q over len(qs) - 1 steps of ds: configurations into qs, g0 into dq
    (rows of the grid), the target rows (P, O, dP/ds, dO/ds at the grid and the RK4
    midpoints: row 2k is node k). progress[0] is the step under way, for a caller whose
    call raised (numpy's LinAlgError from a singular system); a rate or configuration that
    is not finite leaves NaN rows from the next node on (:func:`_blown_up`). Returns the
    largest position and orientation errors after the projections."""
    n_steps = len(qs) - 1
    progress[0] = 0
    q, ep, eo, task = _project(chains, active, gains, rank, target, 0, q, 0, 0.0)
    max_ep, max_eo = ep, eo
    qs[0] = q
    for k in range(n_steps):
        progress[0] = k
        k1, dq[k] = _rate(chains, active, stroke, gains, rank, target, 2 * k, q, task)
        total, slope = k1.copy(), k1
        for stage in range(3):          # RK4's stages 2-4: from q by ds/2, ds/2, ds along the last slope
            last = stage == 2
            x = q + (1.0 if last else 0.5) * ds * slope
            if not _finite(x):
                _blown_up(qs, dq, k)
                return max_ep, max_eo
            row = 2 * k + 2 if last else 2 * k + 1      # the target at the node ahead or the midpoint
            slope = _rate(chains, active, stroke, gains, rank, target, row, x, _task(chains, active, x))[0]
            total += (1.0 if last else 2.0) * slope
        q = q + total * (ds / 6.0)
        if not _finite(q):
            _blown_up(qs, dq, k)
            return max_ep, max_eo
        q, ep, eo, task = _project(chains, active, gains, rank, target, 2 * k + 2, q, iterations, tolerance)
        max_ep, max_eo = max(max_ep, ep), max(max_eo, eo)
        qs[k + 1] = q
    progress[0] = n_steps
    dq[n_steps] = _rate(chains, active, stroke, gains, rank, target, 2 * n_steps, q, task)[1]
    return max_ep, max_eo


def warm() -> None:
    """Load (or, the first time after an installation, compile) the kernel now rather than at
    the first path: a 5-axis toy chain (x, y, z on the tool; a, c under the workpiece) held at
    one pose over the fewest steps, with the argument types :func:`trajectory.redundancy.
    resolve` passes."""
    rot = np.repeat(np.eye(3)[None], 5, axis=0)
    chains = (rot, np.zeros((5, 3)), np.array([False, False, True, True, True]), np.array([0, 2, 0, 1, 2]),
              np.array([3, 4, 0, 1, 2]), np.array([0, 0, 1, 1, 1]), rot[:2].copy(), np.zeros((2, 3)))
    q0 = np.array([0.0, 0.0, 0.0, 0.3, 0.2])
    p, o, _ = pose_jacobian(chains, q0)
    rows = 2 * 6 + 1
    target = (np.repeat(p[None], rows, 0), np.repeat(o[None], rows, 0), np.zeros((rows, 3)), np.zeros((rows, 3)))
    stroke = (np.array([0, 1, 2]), np.zeros(3), np.ones(3))
    integrate(chains, np.arange(5), stroke, (1e-5, 1e3, 1e-3, 1e-6), 5, 2, 1e-13, target, 1e-4, q0,
              np.empty((7, 5)), np.empty((7, 5)), np.zeros(1, np.int64))
