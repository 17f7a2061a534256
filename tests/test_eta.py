"""The training bar's time left: the median of the recent steps, which a validation pause or a burst of load does
not swing."""

from __future__ import annotations

from particlesplat.training.eta import StepTimes, format_duration


def test_time_left_is_the_median_step_times_the_steps_left():
    times = StepTimes(window=5)
    assert times.eta(100) == "?" and times.median() is None
    for s in (1.0, 1.2, 0.8, 1.1, 0.9):
        times.add(s)
    assert times.median() == 1.0 and times.eta(3600) == "1h00m"
    times.add(600.0)  # a step with a validation in it (or another job's burst)
    assert times.median() == 1.1  # one slow step among five moves the median to the next step, not by minutes
    for _ in range(5):
        times.add(2.0)  # the machine got busier: the window follows
    assert times.median() == 2.0 and times.eta(90) == "3m00s"


def test_format_duration():
    assert [format_duration(s) for s in (0, 12.4, 65, 3725, 2 * 86400 + 3 * 3600 + 59)] == [
        "0s",
        "12s",
        "1m05s",
        "1h02m",
        "2d03h",
    ]
