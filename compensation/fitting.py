"""Quintic fits of measured geometric errors (Yuen thesis, seed 000_d9dd5f6a818770e4.txt,
§5.3, Eqs. 5.9-5.13): average the repeats at each position (Eq. 5.9), fit
eps(q) = phi_A u^5 + ... + phi_F (Eq. 5.13) by least squares (Eqs. 5.10-5.12) in the
normalized position u of error_map.py (the thesis's q^5...1 in metres would make Phi^T Phi
condition-numbered ~1e17 on an 80 mm range; in u it is ~2e3, cond Phi ~40), and report the residuals. Solved with lstsq
(the minimizer of Eq. 5.11, as Eq. 5.12, without forming Phi^T Phi)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from compensation.error_map import AxisErrors, ErrorMap
from compensation.measurement import Series

DEGREE = 5             # thesis §5.3: quintic, for jerk continuity


@dataclass(frozen=True)
class FitResidual:
    axis: str
    error: str
    positions: int
    repeats: int
    rms: float          # of averaged readings minus fit (m or rad)
    max: float
    repeatability: float    # largest std of the repeats at one position

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def fit_series(series: Series, span: tuple[float, float]) -> tuple[tuple[float, ...], FitResidual]:
    """Coefficients (highest power first, in u over `span`) and residuals of one series."""
    averaged = series.values.mean(axis=0)                                   # Eq. (5.9)
    lo, hi = span
    u = (2.0 * series.positions - lo - hi) / (hi - lo)
    phi = np.vander(u, DEGREE + 1)                                          # Eq. (5.10)
    theta = np.linalg.lstsq(phi, averaged, rcond=None)[0]                   # Eqs. (5.11)-(5.12)
    residual = averaged - phi @ theta
    spread = series.values.std(axis=0, ddof=1).max() if len(series.values) > 1 else 0.0
    return tuple(float(c) for c in theta), FitResidual(
        series.axis, series.error, len(series.positions), len(series.values),
        float(np.sqrt(np.mean(residual ** 2))), float(np.abs(residual).max()), float(spread))


def fit_map(measurements: list[Series]) -> tuple[ErrorMap, list[FitResidual]]:
    """The error model of a measurement campaign: per axis, one quintic per measured error
    over the measured range (Eq. 5.13); unmeasured errors (roll) are zero, as in the thesis."""
    spans: dict[str, tuple[float, float]] = {}
    for s in measurements:
        lo, hi = spans.get(s.axis, (np.inf, -np.inf))
        spans[s.axis] = (min(lo, float(s.positions[0])), max(hi, float(s.positions[-1])))
    coefficients: dict[str, dict] = {axis: {} for axis in spans}
    residuals = []
    for s in measurements:
        coefficients[s.axis][s.error], residual = fit_series(s, spans[s.axis])
        residuals.append(residual)
    axes = {axis: AxisErrors(spans[axis], coefficients[axis]) for axis in spans}
    return ErrorMap(axes), residuals


def measure_and_fit(truth, true_map: ErrorMap, seed: int, out, by: str):
    """A simulated laser campaign on the machine `truth` (its true map) written to
    OUT/measurement.csv, read back and fitted (Eqs. 5.9-5.13), the model written to
    OUT/model.yaml: (csv path, model path, fitted map, residuals). Reading the CSV back makes
    the fit go through the same path as a real measurement file."""
    from pathlib import Path

    from compensation.error_map import dump_error_map
    from compensation.measurement import campaign, read_csv, write_csv
    out = Path(out)
    csv_path, model_path = out / 'measurement.csv', out / 'model.yaml'
    write_csv(csv_path, campaign(truth, true_map, seed), f'simulated laser campaign ({by})')
    model, residuals = fit_map(read_csv(csv_path, truth.axis_names))
    model_path.write_text(dump_error_map(model, f'fitted from {csv_path} ({by})'))
    return csv_path, model_path, model, residuals
