"""The disturbance Kalman observer (machine_ctrl/identification/disturbance_observer.py)
against the gains the Yuen thesis printed, Eqs. (4.38)-(4.40), from its own model: Table 4.1
m^, b^, Table 4.3 K_a K_t, a 40 nm encoder, 0.025 V command steps, R_wd = 1e-6 and 100 us
(seed-notes.md "Control period")."""
import math
from decimal import Decimal

import numpy as np
import pytest

from machine_ctrl.identification.disturbance_observer import disturbance_observer, quantization_step, thesis_units
from machine_ctrl.identification.status import FitStatus

# as printed, rows x, v, d; columns x_m, v_m (mm and V)
PRINTED = {
    'x_c': ((21.19, 325.91, 45.4), (('0.2227', '2.8518E-6'), ('285.1827', '0.0061'), ('-73.5388', '-0.0020'))),
    'y_c': ((59.17, 346.01, 72.5), (('0.1880', '1.9796E-6'), ('197.9680', '0.0034'), ('-76.1335', '-0.0017'))),
    'z_c': ((17.61, 179.10, 26.17), (('0.1993', '2.2430E-6'), ('224.3086', '0.0042'), ('-75.3177', '-0.0018'))),
}


def _last_digit(text: str) -> float:
    """One unit of the last printed digit."""
    return float(Decimal(1).scaleb(Decimal(text).as_tuple().exponent))


@pytest.mark.parametrize('axis', sorted(PRINTED))
def test_the_thesis_gains_come_back_from_its_own_model(axis):
    """Each gain within 0.1 % or, for those printed to two figures, one unit of the last digit."""
    (mass, viscous, gain), printed = PRINTED[axis]
    design = disturbance_observer(mass, viscous, gain, 1e-4, 40e-9, 0.025)
    assert design.status is FitStatus.OK, design.reason
    ours = thesis_units(design.gain)
    for i, row in enumerate(printed):
        for j, text in enumerate(row):
            value = float(text)
            tolerance = max(1e-3 * abs(value), _last_digit(text))
            assert ours[i, j] == pytest.approx(value, abs=tolerance), (axis, i, j, ours[i, j], text)


def test_the_noise_is_the_quantization_of_eqs_4_33_to_4_36():
    design = disturbance_observer(21.19, 25.05, 45.4, 1e-4, 40e-9, 0.025)
    r_x, r_v, r_u, r_wd = design.noise
    # abs=0: pytest's default absolute tolerance (1e-12) would accept anything near r_x's 1.3e-16
    assert r_x == pytest.approx(40e-9 ** 2 / 12, rel=1e-9, abs=0) and r_v == pytest.approx((40e-9 / 1e-4) ** 2 / 12, rel=1e-9, abs=0)
    assert r_u == pytest.approx(0.025 ** 2 / 12, rel=1e-9, abs=0) and r_wd == 1e-6


@pytest.mark.parametrize('kwargs, named', [
    ({'mass': 0.0}, 'mass 0.0'), ({'damping': -1.0}, 'damping -1.0'), ({'command_step': 0.0}, 'command_step 0.0'),
    ({'position_step': math.nan}, 'position_step nan'), ({'period': -1e-4}, 'period -0.0001'),
])
def test_a_model_without_meaning_is_refused_with_the_value_named(kwargs, named):
    values = {'mass': 21.19, 'damping': 25.05, 'force_gain': 45.4, 'period': 1e-4, 'position_step': 40e-9,
              'command_step': 0.025, **kwargs}
    design = disturbance_observer(**values)
    assert design.status is FitStatus.REFUSED and named in design.reason and design.gain is None


def test_the_quantization_step_of_recorded_values():
    rng = np.random.default_rng(3)
    counts = rng.integers(-2000, 2000, 5000)
    assert quantization_step(counts * 40e-9 + 0.01) == pytest.approx(40e-9, rel=1e-6)   # float residues left out
    assert quantization_step(np.round(rng.normal(0, 1, 5000) / 0.025) * 0.025) == pytest.approx(0.025, rel=1e-9)
    assert math.isnan(quantization_step([1.0, 1.0])) and math.isnan(quantization_step([]))
