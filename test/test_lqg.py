"""The LQG law of Sörnmo section 2.4 (machine_ctrl/control/lqg.py; issue [4/8]) designed from
a model identified from chirp data (test/test_identification.py's y axis: one mode at 47 Hz,
assumed) and closed around the true plant at the identification's 167 Hz: stable, unit
static gain, the resonance damped the more the lower R is (Fig. 2.10), and the reference
notch at the eigenfrequency (section 2.5) removing it."""
import dataclasses
import math

import numpy as np
import pytest
from scipy import signal

from machine_ctrl.control.lqg import LqgController, design, notch
from machine_ctrl.identification.subspace import identify
from test_identification import MODELS, chirp_data, transfer

MODE_HZ = MODELS['y'][0][0][0]                  # 47 Hz


@pytest.fixture(scope='module')
def plant_and_model():
    num, den = transfer(*MODELS['y'])
    u, y, period = chirp_data(num, den)
    result = identify(u, y, period)
    assert result.ok, result.reason
    a, b, c, _, _ = signal.cont2discrete(signal.tf2ss(num, den), period, method='zoh')
    return (a, b[:, 0], c[0], num, den), result


def lqg(result, r_weight=2.5):
    m, noise = result.model, result.noise
    answer = design(m.a, m.b, m.c, float(m.d[0, 0]), m.period, noise.process, noise.measurement, noise.cross,
                    r=r_weight)
    assert answer.ok, answer.reason
    return answer.design


def controller(result, r_weight=2.5, reference_notch=None):
    return LqgController(lqg(result, r_weight), reference_notch)


def run(plant, law, reference):
    a, b, c = plant[:3]
    x, out = np.zeros(a.shape[0]), []
    for r in reference:
        y = float(c @ x)
        x = a @ x + b * law.step(r, y)
        out.append(y)
    return np.array(out)


def amplitude(plant, law, frequency, period, samples=3000):
    law.reset()
    y = run(plant, law, np.sin(2 * math.pi * frequency * np.arange(samples) * period))
    return np.abs(y[samples // 2:]).max()


def closed_loop_radius(plant, law):
    """Spectral radius of the loop (true plant, estimate, disturbance state, integral) at r = 0,
    its matrix built column by column from the controller's own step."""
    a, b, c = plant[:3]
    n, m = a.shape[0], len(law.estimate)
    columns = []
    for j in range(n + m + 1):
        z = np.eye(n + m + 1)[j]
        x, law.estimate, law.integral = z[:n].copy(), z[n:n + m].copy(), float(z[-1])
        u = law.step(0.0, float(c @ x))
        columns.append(np.concatenate([a @ x + b * u, law.estimate, [law.integral]]))
    law.reset()
    return float(np.abs(np.linalg.eigvals(np.array(columns).T)).max())


def test_the_loop_is_stable_and_follows_a_step_with_unit_static_gain(plant_and_model):
    plant, result = plant_and_model
    law = controller(result)
    assert closed_loop_radius(plant, law) < 1.0
    step = run(plant, law, np.ones(2000))
    assert step[-200:] == pytest.approx(1.0, abs=1e-3)


def test_l_r_alone_gives_unit_static_gain(plant_and_model):
    """Section 2.4: l_r "tuned such that the gain is 1" — the loop without its integral state
    (which would force 1 whatever l_r is) settles at 1 on the model it was designed for (the
    identified one taken strictly proper, D = 0, as the physical stage is; the test loop
    reads y before the law's u)."""
    _, result = plant_and_model
    m, noise = result.model, result.noise
    answer = design(m.a, m.b, m.c, 0.0, m.period, noise.process, noise.measurement, noise.cross)
    assert answer.ok, answer.reason
    law = LqgController(dataclasses.replace(answer.design, integral_gain=0.0))
    model_plant = (m.a, m.b[:, 0], m.c[0])            # (the integral state, no longer fed back, just counts)
    assert run(model_plant, law, np.ones(3000))[-100:] == pytest.approx(1.0, abs=1e-6)
    assert answer.design.reference_gain != pytest.approx(1.0, abs=0.01)     # not 1 by itself


def test_a_design_or_a_notch_that_cannot_be_made_says_why(plant_and_model):
    _, result = plant_and_model
    m, noise = result.model, result.noise
    blind = design(m.a, m.b, 0.0 * m.c, 0.0, m.period, noise.process, noise.measurement, noise.cross)
    assert not blind.ok and blind.reason.startswith('no LQG design for this model')
    assert 'must be positive' in design(m.a, m.b, m.c, 0.0, m.period, noise.process, noise.measurement,
                                        noise.cross, r=0.0).reason
    for bad in (0.0, 0.5 / m.period, 200.0):
        with pytest.raises(ValueError, match='Nyquist band'):
            notch(bad, m.period)


def test_a_lower_r_damps_the_resonance_more(plant_and_model):
    """Fig. 2.10 (Q = I, R = 1..4): "a lower weight results in a more aggressive controller,
    where the resonance in the system is well damped"; all of them below the open loop's
    1 / (2 zeta) = 12.5 at the mode."""
    plant, result = plant_and_model
    period = result.model.period
    peaks = [amplitude(plant, controller(result, r), MODE_HZ, period) for r in (1.0, 2.5, 4.0)]
    open_loop = abs(np.polyval(plant[3], 2j * math.pi * MODE_HZ) / np.polyval(plant[4], 2j * math.pi * MODE_HZ))
    assert open_loop == pytest.approx(12.5, rel=1e-6)
    assert peaks[0] < peaks[1] < peaks[2] < open_loop, peaks


def test_the_reference_notch_removes_the_eigenfrequency_and_passes_slow_motion(plant_and_model):
    plant, result = plant_and_model
    period = result.model.period
    plain, notched = controller(result), controller(result, reference_notch=notch(MODE_HZ, period))
    assert amplitude(plant, notched, MODE_HZ, period) < 1e-3 * amplitude(plant, plain, MODE_HZ, period)
    assert amplitude(plant, notched, 2.0, period, 6000) == pytest.approx(amplitude(plant, plain, 2.0, period, 6000),
                                                                          rel=0.02)
    f = notch(MODE_HZ, period)
    b, a = [f.b0, f.b1, f.b2], [1.0, f.a1, f.a2]
    assert abs(np.polyval(b, 1.0) / np.polyval(a, 1.0)) == pytest.approx(1.0)            # unit gain at DC
    z = np.exp(2j * math.pi * MODE_HZ * period)
    assert abs(np.polyval(b, z) / np.polyval(a, z)) < 1e-12                              # the zero at the centre
