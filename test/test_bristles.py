"""machine_ctrl/identification/bristles.py on synthetic presliding steps: the responses of a
LuGre axis of known sigma0, sigma1, quantized to a 40 nm encoder, give them back; data that
cannot are refused with the reason. The responses come from the module's forward model
(`simulate`), so this checks the inverse (the fit) alone; the forward model against hw_sim's
plant, an integration of its own, is test_identify.py's (the micromill's bristles come back
within 10 % from hw_sim's steps)."""
import numpy as np
import pytest

from machine_ctrl.control.lugre import StribeckCurve
from machine_ctrl.identification.bristles import PreslidingStep, fit_bristles, simulate
from machine_ctrl.identification.status import FitStatus

PERIOD, MASS, VISCOUS = 1e-4, 20.0, 25.0
CURVE = StribeckCurve((36.0, 29.0), (40.0, 27.0), (1.3e-3, 3.4e-4), (1.8e-3, 4.5e-4))


def steps(sigma0=6e6, sigma1=2e4, count=40e-9):
    made = []
    for force in (16.0, -13.0):
        blank = PreslidingStep(force, np.zeros(300), CURVE)
        exact = simulate(blank, PERIOD, MASS, VISCOUS, sigma0, sigma1)
        made.append(PreslidingStep(force, np.round(exact / count) * count, CURVE))
    return made


def test_known_bristles_come_back_from_quantized_steps():
    """From a start 3x off in both: within 1 % (the encoder counts are the only error)."""
    fit = fit_bristles(steps(), PERIOD, MASS, VISCOUS, (2e6, 6e4))
    assert fit.status is FitStatus.OK, fit.reason
    assert fit.sigma0 == pytest.approx(6e6, rel=0.01) and fit.sigma1 == pytest.approx(2e4, rel=0.01)
    assert fit.residual_rms < 40e-9 and fit.steps == 2


def test_steps_below_one_count_and_bad_models_are_refused():
    flat = [PreslidingStep(1e-3, np.zeros(50), CURVE)]
    assert 'moved no encoder count' in fit_bristles(flat, PERIOD, MASS, VISCOUS, (1e6, 1e4)).reason
    assert fit_bristles([], PERIOD, MASS, VISCOUS, (1e6, 1e4)).status is FitStatus.REFUSED
    assert 'need m > 0' in fit_bristles(steps(), PERIOD, 0.0, VISCOUS, (1e6, 1e4)).reason
