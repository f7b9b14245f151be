"""The one control-law interface (machine_ctrl/control/law.py) and the registry by name
(machine_ctrl/control/registry.py): every registered law implements the protocol and
declares its gains, names agree with the machine-config schema, unknown names are refused
with one line, and reset() returns a law to its first run bit for bit."""
import dataclasses
import math
import shutil
import typing
from pathlib import Path

import pytest

from machine_ctrl.control.dual_stage import DualStageCoupling
from machine_ctrl.control.law import ControlLaw
from machine_ctrl.control.registry import LAWS, LawEntry, make_law
from machine_ctrl.control.servo import AxisServo, ServoGroup
from machine_ctrl.model.config import CONTROL_LAWS, ControlConfig, PPIGains, load_machine
from machine_ctrl.model.errors import ConfigError

MACHINES = Path(__file__).resolve().parents[1] / 'config' / 'machines'

# the machine (a conftest fixture) and axis whose config carries each law's gains
AXIS_FOR_LAW = {'sliding_mode': ('micromill', 'x_c'), 'ppi': ('micromill', 'x_c'),
                'lead_lag': ('micromill', 'x_f'), 'pid': ('fts_lathe', 'w'), 'h2': ('fts_lathe', 'w'),
                'position_command': ('robot_piezo', 'j2'), 'lqg': ('robot_piezo', 'py')}


@pytest.fixture
def law_axis(request):
    """(axis, period) of the law named by the test's `name` parameter."""
    machine_fixture, axis = AXIS_FOR_LAW[request.getfixturevalue('name')]
    machine = request.getfixturevalue(machine_fixture)
    return machine.axis(axis), machine.control_period


def inputs(steps=3000, period=1e-4):
    """A deterministic 50 Hz reference and a measurement lagging it, (x_r, v_r, a_r, x, v)."""
    w = 2 * math.pi * 50.0
    rows = []
    for k in range(steps):
        t = k * period
        x_r, v_r, a_r = 1e-4 * math.sin(w * t), 1e-4 * w * math.cos(w * t), -1e-4 * w * w * math.sin(w * t)
        rows.append((x_r, v_r, a_r, x_r - 2e-6 * math.cos(w * t), 0.98 * v_r))
    return rows


def run(block, rows):
    return [block.step(*row) for row in rows]


def test_the_registry_names_exactly_the_laws_of_the_config_schema():
    assert set(LAWS) == set(CONTROL_LAWS) == {'sliding_mode', 'ppi', 'lead_lag', 'pid', 'h2', 'position_command', 'lqg'}
    hints = typing.get_type_hints(ControlConfig)
    for name, entry in LAWS.items():
        assert entry.gains in typing.get_args(hints[name]), name     # ControlConfig.<name>: Gains | None


@pytest.mark.parametrize('name', sorted(LAWS))
def test_each_law_implements_the_protocol_and_declares_its_gains(law_axis, name):
    entry = LAWS[name]
    law = make_law(*law_axis, name)
    assert isinstance(law, entry.law) and isinstance(law, ControlLaw)
    declared = [p.name for p in entry.law.parameters]
    assert declared == [f.name for f in dataclasses.fields(entry.gains)]
    assert all(p.unit and p.description for p in entry.law.parameters)
    outputs = run(law, inputs(10))
    assert len(outputs) == 10 and all(math.isfinite(u) for u in outputs)


@pytest.mark.parametrize('name', sorted(LAWS))
def test_reset_reproduces_the_first_run_bit_for_bit(law_axis, name):
    law = make_law(*law_axis, name)
    rows = inputs()
    first = run(law, rows)
    law.reset()
    assert run(law, rows) == first
    assert run(make_law(*law_axis, name), rows) == first    # = a fresh law


def test_reset_of_servos_with_friction_feedforward_and_of_the_coupling(micromill):
    servo = AxisServo(micromill.axis('x_c'), micromill.control_period)
    assert servo.friction is not None                                # sliding mode + LuGre
    rows = inputs()
    first = run(servo, rows)
    servo.reset()
    assert run(servo, rows) == first

    group = ServoGroup(micromill, ['x_c', 'x_f'])
    pairs = [([r[0]] * 2, [r[1]] * 2, [r[2]] * 2, [r[3]] * 2, [r[4]] * 2) for r in rows]
    first = [group.step(*p) for p in pairs]
    group.reset()
    assert [group.step(*p) for p in pairs] == first

    coupling = DualStageCoupling(micromill)
    n = len(micromill.axis_names)
    frames = [([r[0]] * n, [r[3]] * n) for r in rows]
    first = [coupling.step(*f) for f in frames]
    coupling.reset()
    assert [coupling.step(*f) for f in frames] == first


def test_an_unknown_law_name_is_refused_with_one_line(micromill):
    with pytest.raises(ValueError) as info:
        ServoGroup(micromill, ['x_c'], laws={'x_c': 'hinf'})
    assert str(info.value) == "axis x_c: unknown control law 'hinf' (known: h2, lead_lag, lqg, pid, position_command, ppi, sliding_mode)"


def test_a_law_without_gains_or_an_axis_without_control_is_refused(micromill):
    with pytest.raises(ValueError, match=r"^axis x_f: law 'ppi' has no gains in the machine config$"):
        ServoGroup(micromill, ['x_f'], laws={'x_f': 'ppi'})
    bare = dataclasses.replace(micromill.axis('x_c'), control=None)
    with pytest.raises(ValueError, match=r'^axis x_c: no control section in the machine config$'):
        make_law(bare, micromill.control_period)


def test_an_unknown_law_in_the_yaml_is_a_config_error(tmp_path):
    shutil.copy(MACHINES / 'trt_5axis.urdf', tmp_path)
    text = (MACHINES / 'trt_5axis.yaml').read_text()
    assert 'law: sliding_mode' in text
    (tmp_path / 'm.yaml').write_text(text.replace('law: sliding_mode', 'law: hinf', 1))
    with pytest.raises(ConfigError) as info:
        load_machine(tmp_path / 'm.yaml')
    expected = "axes.x.control.law: must be one of h2, lead_lag, lqg, pid, position_command, ppi, sliding_mode, got 'hinf'"
    assert str(info.value).endswith(expected)


class PositionOnly:
    """A stand-in law: u = K_p (x_r - x), reading the ppi gains section."""
    parameters = ()

    @classmethod
    def from_axis(cls, gains, axis, period):
        return cls(gains.position_gain)

    def __init__(self, k_p):
        self.k_p = k_p

    def reset(self):
        pass

    def step(self, x_r, v_r, a_r, x, v, acc=0.0):
        return self.k_p * (x_r - x)


def test_the_servo_picks_laws_through_the_registry_alone(micromill, monkeypatch):
    """Replacing a registry entry is all it takes: no other code branches on the name (and an
    entry without friction feed-forward gets none, though the axis configures one)."""
    monkeypatch.setitem(LAWS, 'ppi', LawEntry(__name__, 'PositionOnly', PPIGains))
    servo = AxisServo(micromill.axis('x_c'), micromill.control_period, law='ppi')
    assert isinstance(servo.law, PositionOnly) and servo.friction is None
    k_p = micromill.axis('x_c').control.ppi.position_gain
    assert servo.step(3e-6, 0.01, 0.5, 1e-6, 0.02) == k_p * (3e-6 - 1e-6)


# --- retuning: a new parameter set between two steps -----------------------------------------

LIVE = {'sliding_mode': ['bandwidth', 'gain', 'adaptation'],
        'ppi': ['position_gain', 'velocity_gain', 'velocity_integral_gain'],
        'lead_lag': [],
        'pid': ['proportional', 'integral', 'derivative'],
        'h2': [],
        'position_command': ['velocity_lead'],
        'lqg': []}


@pytest.mark.parametrize('name', sorted(LAWS))
def test_live_gains_are_declared_with_why_they_are_safe(name):
    from machine_ctrl import parameters
    from machine_ctrl.control.law import live_parameters
    live = live_parameters(LAWS[name].law)
    assert [p.name for p in live] == LIVE[name]
    assert all(len(p.live) > 20 for p in live)
    template = parameters.SERVO.spec('gains.<axis>.<gain>').description       # the README row names them
    assert f'{name} {", ".join(LIVE[name]) or "none"}' in template


def test_a_refused_retune_gives_the_reason_and_changes_nothing(micromill):
    axis = micromill.axis('x_c')
    law = make_law(axis, micromill.control_period)
    gains = law.gains
    rows = inputs(200)
    refused = {
        'disturbance_bounds: fixed while running (a new value needs a new law)': dataclasses.replace(
            gains, disturbance_bounds=(-2.0, 2.0)),
        'gain: must be > 0, got -1': dataclasses.replace(gains, gain=-1.0),
        'bandwidth: must be finite, got nan': dataclasses.replace(gains, bandwidth=math.nan),
        'adaptation: must be >= 0, got -5': dataclasses.replace(gains, adaptation=-5.0),
        'gains must be SlidingModeGains, got PPIGains': axis.control.ppi,
    }
    for reason, new in refused.items():
        assert law.retune_problem(new) == reason
        with pytest.raises(ValueError) as info:
            law.retune(new)
        assert str(info.value) == reason and law.gains is gains
    unstable = dataclasses.replace(gains, gain=5000.0)
    assert law.retune_problem(unstable).startswith('gain: T (K_s / m_e + lambda) = 1.09 must be < 1')
    assert run(law, rows) == run(make_law(axis, micromill.control_period), rows)    # nothing changed


def test_a_retune_takes_effect_from_the_next_step_and_keeps_the_state(micromill):
    axis, period = micromill.axis('x_c'), micromill.control_period
    rows = inputs(400)
    new = dataclasses.replace(axis.control.sliding_mode, gain=60.0, bandwidth=150.0, adaptation=0.0)
    law = make_law(axis, period)
    law.retune(new)                         # before the first step: the same law as one built with them
    built = make_law(dataclasses.replace(axis, control=dataclasses.replace(axis.control, sliding_mode=new)), period)
    assert run(law, rows) == run(built, rows)

    law = make_law(axis, period)
    first = run(law, rows[:200])
    d_hat = law.d_hat
    law.retune(new)
    assert law.d_hat == d_hat and law.gains == new          # the disturbance estimate is kept
    m_e, b_e = axis.drive.mass / axis.drive.gain, axis.drive.damping / axis.drive.gain     # Eq. 4.46, from the config
    assert law.step(*rows[200]) == pytest.approx(m_e * (150.0 * (rows[200][1] - rows[200][4]) + rows[200][2])
                                                 + b_e * rows[200][4] + d_hat
                                                 + 60.0 * ((rows[200][1] - rows[200][4]) + 150.0 * (rows[200][0] - rows[200][3])),
                                                 rel=1e-12)
    assert law.d_hat == d_hat                                # adaptation 0: frozen
    assert first == run(make_law(axis, period), rows[:200])


def test_ppi_retune_is_bumpless_and_refuses_switching_the_integrator(micromill):
    axis, period = micromill.axis('x_c'), micromill.control_period
    law = make_law(axis, period, 'ppi')
    run(law, inputs(500))
    held = law.k_vi * law.integral                           # the force the integrator holds
    gains = law.gains
    law.retune(dataclasses.replace(gains, velocity_integral_gain=2 * gains.velocity_integral_gain))
    assert law.k_vi * law.integral == pytest.approx(held, rel=1e-15)
    reason = law.retune_problem(dataclasses.replace(law.gains, velocity_integral_gain=0.0))
    assert reason.startswith('velocity_integral_gain: switching the integral action off is not bumpless')


def test_lead_lag_takes_no_new_gains_but_its_own(micromill):
    axis, period = micromill.axis('x_f'), micromill.control_period
    law = make_law(axis, period)
    rows = inputs(300)
    assert law.retune_problem(dataclasses.replace(law.gains, alpha=100.0)) == \
        'alpha: fixed while running (a new value needs a new law)'
    law.retune(law.gains)                                    # the gains in use: nothing to do
    assert run(law, rows) == run(make_law(axis, period), rows)


def test_feedforward_switches_at_the_first_step_at_rest(micromill):
    moving, rest = inputs(300), [(r[0], 0.0, 0.0, r[3], r[4]) for r in inputs(50)]

    def rows(data):
        return [([r[0]] * 3, [r[1]] * 3, [r[2]] * 3, [r[3]] * 3, [r[4]] * 3) for r in data]
    asked, kept = ServoGroup(micromill, ['x_c', 'y_c', 'z_c']), ServoGroup(micromill, ['x_c', 'y_c', 'z_c'])
    asked.set_feedforward(False)
    assert (asked.feedforward, asked.feedforward_requested) == (True, False)
    assert [asked.step(*r) for r in rows(moving)] == [kept.step(*r) for r in rows(moving)]    # not under motion
    assert asked.feedforward is True
    asked.step(*rows(rest)[0])
    assert (asked.feedforward, asked.feedforward_requested) == (False, None)
    assert all(s.feedforward is False and s._friction_active is None for s in asked.servos)
    asked.set_feedforward(True)
    asked.step(*rows(rest)[1])                               # on again at rest: friction from zero bristles
    assert asked.feedforward is True and asked.servos[0]._friction_active is asked.servos[0].friction
    off = ServoGroup(micromill, ['x_c'], feedforward=False)  # off from the start: the law alone
    assert off.servos[0].friction is not None and off.servos[0]._friction_active is None
