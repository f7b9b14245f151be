import pytest

from machine_ctrl.control.dual_stage import DualStageCoupling


def full(machine, **values):
    return [values.get(n, 0.0) for n in machine.axis_names]


def test_offsets_are_the_coarse_tracking_errors_with_sign(micromill):
    coupling = DualStageCoupling(micromill)
    assert coupling.fine_axes == ('x_f', 'y_f', 'z_f')
    result = coupling.step(full(micromill, x_c=0.010, y_c=-0.02, z_c=0.03),
                           full(micromill, x_c=0.010 - 3e-6, y_c=-0.02 + 2e-6, z_c=0.03 - 1e-6))
    assert result.offsets == pytest.approx((3e-6, -2e-6, -1e-6))    # z: -e_c (seed-notes)
    assert result.saturated == (False, False, False)


def test_fine_stroke_is_kept_and_saturation_reported(micromill):
    coupling = DualStageCoupling(micromill)                          # x_f stroke +-100 um, 10 % margin
    result = coupling.step(full(micromill, x_c=0.0, x_f=50e-6), full(micromill, x_c=-80e-6))
    assert result.offsets[0] == pytest.approx(80e-6 - 50e-6)
    assert result.saturated[0] and coupling.saturation_count == 1


def test_fine_reference_slews_at_the_fine_velocity_limit(micromill):
    coupling = DualStageCoupling(micromill)
    coupling.step(full(micromill), full(micromill))
    result = coupling.step(full(micromill, x_c=50e-6), full(micromill))  # 50 um coarse error at once
    slew = micromill.axis('x_f').limits.velocity * micromill.control_period   # 2 um per step
    assert result.offsets[0] == pytest.approx(slew) and result.saturated[0]


def test_disabled_coupling_adds_nothing(micromill):
    coupling = DualStageCoupling(micromill, dual_stage=False)
    assert coupling.step(full(micromill, x_c=1.0), full(micromill)).offsets == (0.0, 0.0, 0.0)


def test_reset_forgets_the_slew_history_and_the_saturation_count(micromill):
    coupling = DualStageCoupling(micromill)
    coupling.step(full(micromill), full(micromill))
    coupling.step(full(micromill, x_c=50e-6), full(micromill))         # slewed: one saturation
    coupling.reset()
    assert coupling.saturation_count == 0
    result = coupling.step(full(micromill, x_c=50e-6), full(micromill))  # first step again: no slew
    assert result.offsets[0] == pytest.approx(50e-6) and not result.saturated[0]
