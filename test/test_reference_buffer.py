"""The servo's reference buffer (machine_ctrl.model.reference.ReferenceBuffer): rows by step,
re-plans, underruns held at rest, and a stream that broke while moving taken up again only
from a row at rest where the buffer holds (issue [6/8]: nothing moves without a goal after
a lost link)."""
from machine_ctrl.model.reference import ReferenceBuffer

AXES = ('x', 'y')
TOL = 20e-6


def rows(first_position, steps, velocity=0.0, period=1e-3):
    """`steps` rows from `first_position` on x at `velocity` (y at rest), as chunk lists."""
    positions = [[first_position + velocity * period * k, 0.5] for k in range(steps)]
    moving = [[velocity, 0.0]] * steps
    return positions, moving, [[0.0, 0.0]] * steps


def test_rows_by_step_a_replan_replaces_from_its_first_step_and_an_underrun_holds_at_rest():
    buffer = ReferenceBuffer(AXES, TOL)
    assert buffer.take(0, [0.1, 0.2]) == ([0.1, 0.2], [0.0, 0.0], [0.0, 0.0], True)     # the fallback, before any
    buffer.add(10, *rows(1.0, 5))
    buffer.add(12, *rows(2.0, 5))                                       # a re-plan from step 12
    assert buffer.end_step == 17
    assert buffer.take(11, None)[0] == [1.0, 0.5]                      # step 10 dropped as past
    assert buffer.take(12, None)[0] == [2.0, 0.5]
    assert buffer.take(20, None) == ([2.0, 0.5], [0.0, 0.0], [0.0, 0.0], True)          # ran out: held at rest
    assert buffer.underruns == 2 and buffer.broken_step is None        # the first take and this one: at rest


def test_an_underrun_at_rest_does_not_break_the_stream():
    buffer = ReferenceBuffer(AXES, TOL)
    buffer.add(0, *rows(1.0, 2))
    buffer.take(0, None), buffer.take(1, None)
    assert buffer.take(2, None)[3] and buffer.broken_step is None        # held at rest, no break
    buffer.add(3, *rows(1.0, 3, velocity=0.01))                        # a new motion
    assert buffer.take(3, None) == ([1.0, 0.5], [0.01, 0.0], [0.0, 0.0], False)


def test_a_stream_broken_while_moving_is_held_until_a_row_at_rest_where_it_holds():
    buffer = ReferenceBuffer(AXES, TOL)
    buffer.add(0, *rows(1.0, 10, velocity=0.01))                       # 10 µm per step on x
    for step in range(10):
        buffer.take(step, None)
    held = [1.0 + 0.01e-3 * 9, 0.5]
    assert buffer.take(10, None) == (held, [0.0, 0.0], [0.0, 0.0], True)           # ran out while moving
    assert buffer.broken_step == 10 and buffer.underruns == 1
    # rows that were on their way before the break: they go on moving from where x no longer is
    buffer.add(11, *rows(held[0] + 0.01e-3 * 3, 5, velocity=0.01))
    assert buffer.take(11, None) == (held, [0.0, 0.0], [0.0, 0.0], True)
    assert buffer.refused_rows == 1 and buffer.last_refusal == (
        'step 11: the reference broke at step 10 while moving: holding, this row moves (a row at rest is awaited)')
    # at rest, but where a stop ended (1 mm away): refused, naming the axis and the distance
    buffer.add(12, *rows(held[0] + 1e-3, 2))
    assert buffer.take(12, None)[0] == held and buffer.refused_rows == 2
    assert buffer.last_refusal == ('step 12: the reference broke at step 10 while moving: holding, this row is '
                                   '+0.001 from the held position on x (at most 2e-05 taken up)')
    assert buffer.take(13, None)[0] == held and buffer.broken_step == 10 and buffer.underruns == 1
    # the stream taken up again where the machine stands (5 µm off: within the tolerance)
    buffer.add(14, *rows(held[0] + 5e-6, 2))
    assert buffer.take(14, None) == ([held[0] + 5e-6, 0.5], [0.0, 0.0], [0.0, 0.0], False)
    assert buffer.broken_step is None
    buffer.add(16, *rows(held[0] + 5e-6, 3, velocity=0.01))              # and a new goal moves again
    assert buffer.take(16, None)[1] == [0.01, 0.0]


def test_a_refused_row_or_a_hold_after_a_refusal_never_breaks_again_or_moves():
    """While broken every take holds at rest, so the break stays at its first step and a later
    underrun is no new break; the held position is where the last row taken stood."""
    buffer = ReferenceBuffer(AXES, TOL)
    buffer.add(0, *rows(1.0, 1, velocity=0.01))
    buffer.take(0, None)
    buffer.take(1, None)
    assert buffer.broken_step == 1
    buffer.take(2, None)
    buffer.add(3, *rows(1.0 + 30e-6, 1))
    assert buffer.take(3, None)[0] == [1.0, 0.5] and buffer.broken_step == 1 and buffer.underruns == 2
