"""A frequency response measured with noise: the H1 estimate and its coherence, and the
bandwidths read off a response. Plain numeric functions (numpy, scipy.signal); no ROS, no
simulator.

With an excitation r (the reference, known exactly) and a measured output y, Welch's averaged
spectra over segments of `segment` samples (Hann windows, half overlap; scipy.signal.csd and
welch) give

    H1(f) = S_ry(f) / S_rr(f)                     the response: unbiased by noise on y
    gamma^2(f) = |S_ry|^2 / (S_rr S_yy)          the coherence, 0..1

The coherence is the share of y's power at f that is linear in r: 1 for a linear system without
noise, lower where the output carries noise or what a nonlinearity (friction, saturation)
makes of r at other frequencies. A reading of H1 where gamma^2 is low is not one to trust;
:func:`coherent_bandwidth` says so beside its -3 dB point.

:func:`band_limited_noise` is an excitation for it: Gaussian noise shaped in frequency
(flat, or pink: power falling as 1/f, so a position excitation keeps its velocity and
acceleration modest) inside a band, scaled to an rms, from a seeded generator.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.identification.status import FitStatus

HALF_POWER = 1.0 / math.sqrt(2.0)      # |T| at the -3 dB point (-3.0103 dB, half the power)


@dataclass(frozen=True)
class FrequencyResponse:
    """An H1 estimate: `response` (complex, output per excitation) and `coherence` at
    `frequencies` (Hz, without 0), `segments` Welch averages; status and reason as every fit."""
    status: FitStatus
    reason: str
    frequencies: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    segments: int = 0

    def at(self, f: float) -> tuple[complex, float]:
        """(response, coherence) at the line nearest `f` Hz."""
        k = int(np.argmin(np.abs(self.frequencies - f)))
        return complex(self.response[k]), float(self.coherence[k])


def band_limited_noise(samples: int, rate: float, band: tuple[float, float], rms: float,
                       rng: np.random.Generator, pink: bool = True) -> np.ndarray:
    """`samples` of Gaussian noise at `rate` Hz with its power only inside `band` (Hz), flat or
    (`pink`) falling as 1/f, scaled to `rms` (zero mean). ValueError for a band that is not
    0 < low < high <= rate / 2."""
    if not 0.0 < band[0] < band[1] <= 0.5 * rate:
        raise ValueError(f'band {band[0]:g}-{band[1]:g} Hz: it must be 0 < low < high <= {0.5 * rate:g} Hz (rate / 2)')
    spectrum = np.fft.rfft(rng.standard_normal(samples))
    f = np.fft.rfftfreq(samples, 1.0 / rate)
    inside = (f >= band[0]) & (f <= band[1])
    shape = np.zeros_like(f)
    shape[inside] = 1.0 / np.sqrt(f[inside]) if pink else 1.0
    x = np.fft.irfft(spectrum * shape, samples)
    return x * (rms / x.std())


def estimate(excitation, output, rate: float, segment: int) -> FrequencyResponse:
    """H1 and coherence of `output` against `excitation` (module docstring), both sampled at
    `rate` Hz; refused (with the reason) for data that cannot give them."""
    from scipy import signal
    r, y = np.asarray(excitation, float), np.asarray(output, float)
    empty = np.array([])

    def refused(reason):
        return FrequencyResponse(FitStatus.REFUSED, reason, empty, empty.astype(complex), empty)
    if r.shape != y.shape or r.ndim != 1:
        return refused(f'excitation and output must be equally long 1-d series, got {r.shape} and {y.shape}')
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(y))):
        return refused('the data holds NaN or inf')
    if segment < 16 or len(r) < 4 * segment:
        return refused(f'{len(r)} samples for segments of {segment}: at least 4 segments of 16 samples or more needed')
    if not np.ptp(r) > 0:
        return refused('the excitation is constant: it excites nothing')
    f, s_ry = signal.csd(r, y, rate, nperseg=segment)
    _, s_rr = signal.welch(r, rate, nperseg=segment)
    _, s_yy = signal.welch(y, rate, nperseg=segment)
    keep = (f > 0) & (s_rr > 0)
    with np.errstate(invalid='ignore', divide='ignore'):
        coherence = np.where(s_yy > 0, np.abs(s_ry) ** 2 / (s_rr * s_yy), 0.0)
    segments = 1 + (len(r) - segment) // (segment // 2)
    return FrequencyResponse(FitStatus.OK, '', f[keep], s_ry[keep] / s_rr[keep], coherence[keep], segments)


def bandwidth(frequencies, gains) -> float | None:
    """The first fall of |gain| below the half-power level 1/sqrt(2), interpolated in log f and
    log |gain|; None if it never falls (or starts below)."""
    return _first_fall(frequencies, np.abs(np.asarray(gains)), HALF_POWER)


def crossover(frequencies, open_loop) -> float | None:
    """The first fall of |open_loop| through 1 (the open loop's crossover), interpolated alike;
    None if none."""
    return _first_fall(frequencies, np.abs(np.asarray(open_loop)), 1.0)


def coherent_bandwidth(response: FrequencyResponse, min_coherence: float) -> tuple[float | None, float]:
    """The -3 dB point of `response` (:func:`bandwidth`) and the coherence there (interpolated
    between the two lines around it); None when it has none or the coherence there is below
    `min_coherence` (a crossing read from noise or distortion is not reported)."""
    f, gains = response.frequencies, np.abs(response.response)
    found = bandwidth(f, gains)
    if found is None:
        return None, math.nan
    coherence = float(np.interp(math.log(found), np.log(f), response.coherence))
    return (found if coherence >= min_coherence else None), coherence


def coherent_band(response: FrequencyResponse, min_coherence: float) -> tuple[float, float] | None:
    """The lowest and highest frequency (Hz) of the widest run of consecutive lines whose
    coherence is at least `min_coherence`, width measured in log frequency (a decade counts
    alike wherever it lies; the lines are equally spaced, so a count of lines would favour the
    high frequencies), or None."""
    good = np.concatenate(([False], response.coherence >= min_coherence, [False]))
    edges = np.flatnonzero(np.diff(good.astype(int)))
    if len(edges) == 0:
        return None
    f = response.frequencies
    starts, stops = edges[0::2], edges[1::2] - 1
    widest = int(np.argmax(np.log(f[stops]) - np.log(f[starts])))
    return float(f[starts[widest]]), float(f[stops[widest]])


def _first_fall(frequencies, gains, level: float) -> float | None:
    below = np.nonzero(gains < level)[0]
    if len(below) == 0 or below[0] == 0:
        return None
    i = below[0]
    f0, f1, g0, g1 = frequencies[i - 1], frequencies[i], gains[i - 1], gains[i]
    w = (math.log(g0) - math.log(level)) / (math.log(g0) - math.log(g1))
    return float(math.exp(math.log(f0) + w * (math.log(f1) - math.log(f0))))
