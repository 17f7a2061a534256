"""When the idle frame loop draws (viewer.redraw.RedrawSchedule), without a window."""

from __future__ import annotations

from viewer.redraw import SETTLE_FRAMES, RedrawSchedule


def test_draws_after_events_then_sleeps_until_the_next():
    s = RedrawSchedule()
    for _ in range(SETTLE_FRAMES):  # the first frames of a window
        assert s.timeout(0.0) == 0.0 and s.due(0.0)
        s.drawn(changed=False, wake_at=None)
    assert s.timeout(0.0) is None and not s.due(1e9)  # idle: wait for an event, however long
    s.notify(object(), 10.0, 20.0)  # any glfw callback's arguments
    assert s.events == 1 and s.timeout(5.0) == 0.0
    s.drawn(changed=True, wake_at=None)  # a change (an edit, a request) draws one frame more ...
    s.drawn(changed=True, wake_at=None)
    s.drawn(changed=True, wake_at=None)
    assert s.due(0.0)
    s.drawn(changed=False, wake_at=None)  # ... until a frame changes nothing
    assert s.timeout(0.0) is None


def test_timed_redraw_after_motion():
    s = RedrawSchedule(pending=1)
    s.drawn(changed=True, wake_at=10.2)  # a moving frame: the full-scale frame is due at 10.2
    s.drawn(changed=False, wake_at=10.2)
    assert abs(s.timeout(10.0) - 0.2) < 1e-9
    assert not s.due(10.1) and s.due(10.2)
    s.drawn(changed=True, wake_at=None)  # the full-scale frame re-rendered: one more, then nothing
    s.drawn(changed=False, wake_at=None)
    assert s.timeout(11.0) is None
