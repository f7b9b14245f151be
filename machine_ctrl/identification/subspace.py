"""Black-box identification of a discrete state-space model from input-output data by
subspace identification, as Sörnmo identifies the piezo micro manipulator (seed
004_33b29b0855b96c5a, section 2.3): a chirp input, the mean and linear trend removed,
decimation to a rate that suits the eigenfrequencies, the model order read off the gap in
the singular values of the subspace step, and the fit reported as variance accounted for,

    VAF = 100 (1 - var(y - y_model) / var(y))  %          (Johansson 1993, section 2.3)

with y_model the identified model's simulated output for the same input (from rest).
:func:`balanced` and :func:`resampled` carry a model (and its noise) to the balanced state
basis and to another sample period, what a controller designed from it at its own rate needs.

The subspace step is the `nfoursid` library's N4SID (PO-MOESP instrumental variables, QR,
SVD; Van Overschee and De Moor 1994); this module prepares the data, selects the order and
checks what comes back. One step of the library is replaced (:class:`_N4SID`): it takes the
full SVD of a (block rows x samples) matrix, whose right factor is samples x samples (800 MB
and seconds for the 10,000 samples of a 60 s record); the economy SVD gives the same rank-n
factors. Results carry a status and a one-line reason; bad data is refused,
never repaired.

    x_{k+1} = A x_k + B u_k,   y_k = C x_k + D u_k      (Eqs. 2.1-2.2, one input, one output)
"""
from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.linalg import expm, logm, solve_discrete_lyapunov

# assumed: 6 block rows (past and future horizons) see up to 5 states, the seed's largest
# order (z). More let N4SID place poles where a 10-60 Hz chirp gives no data: with 14 rows,
# a model's second mode moved from 58 to 76-84 Hz (towards the 83 Hz Nyquist frequency of
# the decimated data) or came out unstable (test/test_identification.py's models)
BLOCK_ROWS = 6
MAX_ORDER = 10                # orders searched for the singular-value gap (at most block rows - 1)


class Status(enum.Enum):
    OK = 'ok'
    BAD_DATA = 'bad_data'     # refused before identifying: lengths, NaN, too short, no excitation
    FAILED = 'failed'         # the identified model is unusable (unstable, not finite)


@dataclass(frozen=True)
class StateSpaceModel:
    """x_{k+1} = a x_k + b u_k, y_k = c x_k + d u_k at sample period `period` (s)."""
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    period: float

    @property
    def order(self) -> int:
        return self.a.shape[0]

    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.a)

    def static_gain(self) -> float:
        """y / u at rest: C (I - A)^-1 B + D."""
        return float(self.c[0] @ np.linalg.solve(np.eye(self.order) - self.a, self.b[:, 0]) + self.d[0, 0])

    def natural_frequencies(self) -> np.ndarray:
        """|ln z| / (2 pi T) of every pole (Hz, ascending): the continuous modes it samples."""
        return np.sort(np.abs(np.log(self.poles().astype(complex))) / (2 * math.pi * self.period))

    def simulate(self, u: np.ndarray) -> np.ndarray:
        """Output for input `u` from rest."""
        x = np.zeros(self.order)
        y = np.empty(len(u))
        a, b, c, d = self.a, self.b[:, 0], self.c[0], float(self.d[0, 0])
        for k, uk in enumerate(u):
            y[k] = c @ x + d * uk
            x = a @ x + b * uk
        return y


@dataclass(frozen=True)
class NoiseCovariance:
    """Covariances of the innovation form's residuals (nfoursid): process w (n x n), measurement
    v (1 x 1), their cross term s = E[w v'] (n x 1); what a Kalman filter of the model needs."""
    process: np.ndarray
    measurement: np.ndarray
    cross: np.ndarray


def balanced(model: StateSpaceModel, noise: NoiseCovariance) -> tuple[StateSpaceModel, NoiseCovariance]:
    """The same model and noise in its balanced realization: both Gramians equal and diagonal
    (the Hankel singular values), each state weighted by its input-output energy. N4SID's state
    basis is arbitrary; this one is unique up to the states' signs, so a weight on the states
    (an LQ design's Q) means the same for every identification. ValueError for a model that is
    not minimal (a Gramian not positive definite)."""
    a, b, c = model.a, model.b, model.c
    radius = float(np.abs(model.poles()).max())
    if radius >= 1.0:
        raise ValueError(f'the model is not stable (pole radius {radius:.4g}): it has no Gramians')
    reach = solve_discrete_lyapunov(a, b @ b.T)
    observe = solve_discrete_lyapunov(a.T, c.T @ c)
    try:
        factor = np.linalg.cholesky(reach)
    except np.linalg.LinAlgError:
        raise ValueError('the model is not minimal: its reachability Gramian is singular') from None
    u, squared, _ = np.linalg.svd(factor.T @ observe @ factor)     # the Hankel singular values squared
    if not squared[-1] > 0.0:
        raise ValueError('the model is not minimal: a Hankel singular value is zero')
    t = factor @ u @ np.diag(squared ** -0.25)          # x = t x_balanced
    ti = np.linalg.inv(t)
    return (StateSpaceModel(ti @ a @ t, ti @ b, c @ t, model.d, model.period),
            NoiseCovariance(ti @ noise.process @ ti.T, noise.measurement, ti @ noise.cross))


def resampled(model: StateSpaceModel, noise: NoiseCovariance, period: float
              ) -> tuple[StateSpaceModel, NoiseCovariance]:
    """The model at another sample period, the same continuous system under a zero-order hold
    (the matrix logarithm of the held model, then its exponential), in the same state basis;
    the noise read as continuous white densities: process covariance x period ratio,
    measurement / ratio, cross term unchanged. ValueError where no real logarithm exists (a
    pole on the negative real axis: no continuous system sampled gives it)."""
    n = model.order
    if model.b.shape[1] != 1:
        raise ValueError(f'one input only, the model has {model.b.shape[1]}')
    held = np.zeros((n + 1, n + 1))
    held[:n, :n], held[:n, n:], held[n, n] = model.a, model.b, 1.0
    poles = model.poles()
    if np.any((np.abs(poles.imag) < 1e-12) & (poles.real <= 0.0)):
        raise ValueError('a pole on the negative real axis: the model is no sampled continuous system')
    generator = np.real(logm(held)) / model.period
    generator[n, :] = 0.0
    out = expm(generator * period)
    ratio = period / model.period
    return (StateSpaceModel(out[:n, :n], out[:n, n:], model.c, model.d, period),
            NoiseCovariance(noise.process * ratio, noise.measurement / ratio, noise.cross))


@dataclass(frozen=True)
class ModalForm:
    """An identified model read as a machine config's piezo model (model/modal.py): its
    continuous poles as lightly damped pairs (omega rad/s, zeta, ascending) and at most one
    real pole (rad/s, 0: none); the static gain taken as 1 and the zeros dropped, which is
    what that form holds. `reason` says why a model has no such form ('' when it has)."""
    modes: tuple[tuple[float, float], ...] = ()
    real_pole: float = 0.0
    reason: str = ''


def modal_form(model: StateSpaceModel) -> ModalForm:
    """The model's :class:`ModalForm`: s = ln(z) / T of each pole. Refused (the reason): a
    pole on or outside the unit circle or at the origin, a real pole at z < 0 (no continuous
    pole samples to it), more than one real pole, a pair with zeta outside (0, 1), no pair."""
    poles = model.poles().astype(complex)
    if np.any(np.abs(poles) >= 1.0) or np.any(np.abs(poles) == 0.0):
        return ModalForm(reason='a pole on or outside the unit circle, or at the origin: no continuous pole')
    real_z = [p for p in poles if abs(p.imag) <= 1e-12]
    if any(p.real < 0.0 for p in real_z):
        return ModalForm(reason='a real pole at z < 0: no continuous pole samples to it')
    s = np.log(poles) / model.period
    pairs = sorted((float(abs(p)), float(-p.real / abs(p))) for p in s if p.imag > 1e-9)
    real = [float(-p.real) for p in s if abs(p.imag) <= 1e-9]
    if 2 * len(pairs) + len(real) != model.order:
        return ModalForm(reason=f'{model.order} poles that are neither conjugate pairs nor real')
    if len(real) > 1:
        return ModalForm(reason=f'{len(real)} real poles ({", ".join(f"{r:.4g}" for r in sorted(real))} rad/s): '
                                'the modal form holds one')
    if not pairs:
        return ModalForm(reason='no pole pair: the modal form needs at least one mode')
    if any(zeta >= 1.0 or zeta <= 0.0 for _, zeta in pairs):
        return ModalForm(reason='a pole pair that is not lightly damped (zeta outside (0, 1))')
    return ModalForm(tuple(pairs), real[0] if real else 0.0)


@dataclass(frozen=True)
class Identification:
    status: Status
    reason: str
    model: StateSpaceModel | None = None
    singular_values: tuple[float, ...] = ()   # of the subspace step, descending (the order plot)
    vaf: float = float('nan')                 # %, on the data identified from
    noise: NoiseCovariance | None = None

    @property
    def ok(self) -> bool:
        return self.status is Status.OK


def chirp(f0: float, f1: float, duration: float, period: float, amplitude: float = 1.0) -> np.ndarray:
    """A sinusoid of constant amplitude whose frequency rises linearly from f0 to f1 Hz over
    `duration` s, sampled at `period` (section 2.3's excitation)."""
    t = np.arange(int(round(duration / period))) * period
    return amplitude * signal.chirp(t, f0=f0, t1=duration, f1=f1, method='linear', phi=-90)


def vaf(y: np.ndarray, y_model: np.ndarray) -> float:
    """Variance accounted for, % (module doc)."""
    return float(100.0 * (1.0 - np.var(y - y_model) / np.var(y)))


def select_order(singular_values, max_order: int = MAX_ORDER) -> int:
    """The order n (1..max_order) after which the singular values drop the most, on a log
    scale: the gap between the model and the noise level (section 2.3)."""
    s = np.asarray(singular_values, dtype=float)[:max_order + 1]
    floor = s[0] * np.finfo(float).eps
    ratios = np.log(np.maximum(s[:-1], floor)) - np.log(np.maximum(s[1:], floor))
    return int(np.argmax(ratios)) + 1


def _problem(u: np.ndarray, y: np.ndarray, period: float, block_rows: int, order, max_order: int) -> str:
    if not (isinstance(block_rows, int) and block_rows >= 2):
        return f'block rows must be an integer >= 2, got {block_rows!r}'
    if order is not None and not (isinstance(order, int) and 1 <= order <= block_rows):
        return f'order {order!r} must be an integer within 1..{block_rows} (the block rows)'
    if order is None and not (isinstance(max_order, int) and max_order >= 1):
        return f'the largest order searched must be an integer >= 1, got {max_order!r}'
    if u.ndim != 1 or y.ndim != 1 or len(u) != len(y):
        return f'input and output must be two series of one length, got shapes {u.shape} and {y.shape}'
    if not (math.isfinite(period) and period > 0):
        return f'sample period must be a positive number of seconds, got {period!r}'
    if not (np.isfinite(u).all() and np.isfinite(y).all()):
        return 'input or output holds NaN or inf'
    if len(u) < 10 * block_rows:
        return f'{len(u)} samples: at least {10 * block_rows} are needed for {block_rows} block rows'
    for name, raw in (('input', u), ('output', y)):      # what is left once mean and trend are removed
        scale = float(np.abs(raw).max())
        if scale == 0.0 or np.std(signal.detrend(raw)) <= 1e-9 * scale:
            return f'the {name} is constant or a straight line: nothing to identify once its mean and trend are removed'
    return ''


@functools.cache
def _n4sid_class():
    """nfoursid's NFourSID with its observability decomposition by the economy SVD (module doc;
    test/test_identification.py checks it against the library's own)."""
    from nfoursid.nfoursid import NFourSID
    from nfoursid.utils import Decomposition, Utils

    class _N4SID(NFourSID):
        def _get_observability_matrix_decomposition(self) -> Decomposition:
            hankel = np.concatenate([Utils.block_hankel_matrix(self.u_array, self.num_block_rows),
                                     Utils.block_hankel_matrix(self.y_array, self.num_block_rows)])
            left, values, right = np.linalg.svd(self.R32 @ np.linalg.pinv(self.R22) @ hankel, full_matrices=False)
            return Utils.reduce_decomposition(Decomposition(left, np.diag(values), right), self.x_dim)
    return _N4SID


def identify(u, y, period: float, order: int | None = None, block_rows: int = BLOCK_ROWS,
             max_order: int = MAX_ORDER) -> Identification:
    """The model of the data (u, y) sampled at `period`: mean and linear trend removed
    (section 2.3), N4SID with `block_rows`, the order given or selected from the singular
    values (:func:`select_order`), VAF on the detrended data."""
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    problem = _problem(u, y, period, block_rows, order, max_order)
    if problem:
        return Identification(Status.BAD_DATA, problem)
    import pandas as pd                      # nfoursid takes a DataFrame
    u, y = signal.detrend(u), signal.detrend(y)
    n4sid = _n4sid_class()(pd.DataFrame({'u': u, 'y': y}), output_columns=['y'], input_columns=['u'],
                           num_block_rows=block_rows)
    n4sid.subspace_identification()
    singular = tuple(float(v) for v in np.diagonal(n4sid.R32_decomposition.eigenvalues))
    n = order if order is not None else select_order(singular, min(max_order, block_rows - 1))
    space, covariance = n4sid.system_identification(rank=n)     # covariance [[v, s'], [s, w]]
    model = StateSpaceModel(np.asarray(space.a), np.asarray(space.b), np.asarray(space.c), np.asarray(space.d),
                            period)
    matrices = (model.a, model.b, model.c, model.d)
    if not all(np.isfinite(m).all() for m in matrices):
        return Identification(Status.FAILED, f'order {n}: the identified matrices are not finite',
                              singular_values=singular)
    radius = float(np.abs(model.poles()).max())
    if radius >= 1.0:
        return Identification(Status.FAILED, f'order {n}: the identified model is unstable (pole radius {radius:.4g})',
                              model, singular)
    noise = NoiseCovariance(covariance[1:, 1:], covariance[:1, :1], covariance[1:, :1])
    return Identification(Status.OK, '', model, singular, vaf(y, model.simulate(u)), noise)
