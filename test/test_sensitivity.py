"""machine_ctrl/experiments/sensitivity.py: the variants change the two chosen plant values
alone (sigma1 critical again by Eq. 4.65, the controllers untouched), and the command prints
every statistic's ratio for each (on the first 2000 steps of the circle: the wiring; the
full tables are in the README)."""
import json

import pytest

from machine_ctrl.experiments.sensitivity import VARIANTS, varied


def test_a_variant_changes_the_bristles_or_the_noise_and_nothing_else(micromill):
    stiff = varied(micromill, sigma0=2.0)
    for before, after in zip(micromill.axes, stiff.axes):
        assert (after.drive, after.control, after.plant.mass) == (before.drive, before.control, before.plant.mass)
        if before.plant.friction is None:
            assert after == before
            continue
        assert after.plant.friction.sigma0 == 2.0 * before.plant.friction.sigma0
    # x_c critically damped again, Eq. (4.65) by hand: 2 sqrt(21.44 kg * 1.8e7 N/m) - 25.05 N s/m
    assert stiff.axis("x_c").plant.friction.sigma1 == pytest.approx(39264.6, abs=0.1)
    noisy = varied(micromill, force_noise=0.5)
    assert [a.plant.force_noise for a in noisy.axes] == [0.5 * a.plant.force_noise for a in micromill.axes]
    assert [a.plant.friction for a in noisy.axes] == [a.plant.friction for a in micromill.axes]


def test_the_command_prints_each_variants_ratio(capsys):
    from machine_ctrl.app import cli
    assert cli.main(['experiment', 'circle', '--sensitivity', '--steps', '2000', '--jobs', '1', '--quiet', '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out['variants']) == {label for label, _, _ in VARIANTS}
    for variant in out['variants'].values():
        for mode in ('smc', 'dsfd'):
            for key, value in out['configured'][mode].items():
                assert variant['ratio'][mode][key] == pytest.approx(variant[mode][key] / value)
    # the dual stage's mean errors are its table's force noise: twice the noise, about twice the error
    doubled = out['variants']['force noise x 2']['ratio']['dsfd']
    assert all(1.6 < doubled[key] < 2.4 for key in ('mean_x_tracking', 'mean_y_tracking')), doubled
    assert cli.main(['experiment', 'frf', '--sensitivity']) == 2
    assert '--sensitivity is for circle and square' in capsys.readouterr().err
