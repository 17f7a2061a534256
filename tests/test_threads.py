"""Threads that fit the free cores: the load arithmetic, the governor on a fake /proc/stat, the CLI's wait policy."""

from __future__ import annotations

import os

import pytest
import torch

from particlesplat.cli import main as cli_main
from particlesplat.core import threads
from particlesplat.core.threads import ThreadGovernor, busy_seconds, other_load, threads_for


def _stat(path, busy_ticks: int, idle_ticks: int = 1000) -> None:
    # user nice system idle iowait irq softirq steal guest guest_nice: busy ticks split over user and system
    path.write_text(f"cpu  {busy_ticks - 7} 0 7 {idle_ticks} 3 0 0 0 0 0\ncpu0 1 2 3 4 5 6 7 8 9 10\n")


@pytest.mark.parametrize(
    ("maximum", "cores", "others", "expected"),
    [
        (2, 2, 0.0, 2),  # free machine
        (2, 2, 0.25, 2),  # a shell and a monitor: still free
        (2, 2, 1.0, 1),  # one core busy
        (2, 2, 2.5, 1),  # oversubscribed: never below one
        (16, 16, 3.2, 13),
        (4, 16, 0.0, 4),  # never above the maximum
    ],
)
def test_threads_for_leaves_the_cores_others_use(maximum, cores, others, expected):
    assert threads_for(maximum, cores, others) == expected


def test_busy_seconds_reads_the_aggregate_line_and_refuses_garbage(tmp_path):
    stat = tmp_path / "stat"
    _stat(stat, busy_ticks=500)
    assert busy_seconds(stat) == pytest.approx(500 / os.sysconf("SC_CLK_TCK"))  # idle and iowait not counted
    stat.write_text("intr 1 2 3\n")
    assert busy_seconds(stat) is None
    assert busy_seconds(tmp_path / "missing") is None


def test_governor_drops_a_thread_while_another_process_keeps_a_core_busy_and_restores_it(tmp_path, monkeypatch):
    hz = os.sysconf("SC_CLK_TCK")
    clock = {"wall": 100.0, "own": 10.0}
    monkeypatch.setattr(threads.time, "monotonic", lambda: clock["wall"])
    monkeypatch.setattr(threads.time, "process_time", lambda: clock["own"])
    set_to: list[int] = []
    monkeypatch.setattr(torch, "set_num_threads", set_to.append)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)
    stat = tmp_path / "stat"
    busy = 1000 * hz
    _stat(stat, busy)
    gov = ThreadGovernor(2, stat)
    gov.cores = 2

    def window(seconds: float, own_cores: float, other_cores: float) -> int:
        nonlocal busy
        clock["wall"] += seconds
        clock["own"] += own_cores * seconds
        busy += round((own_cores + other_cores) * seconds * hz)
        _stat(stat, busy)
        return gov.update()

    assert window(20, own_cores=1.8, other_cores=0.1) == 2 and set_to == []
    assert window(20, own_cores=1.0, other_cores=1.0) == 1 and set_to == [1]
    assert window(20, own_cores=1.0, other_cores=0.9) == 1 and set_to == [1]  # still busy: unchanged
    assert window(20, own_cores=1.0, other_cores=0.0) == 2 and set_to == [1, 2]
    stat.unlink()  # unreadable: the count stays as it is
    assert gov.update() == 2 and set_to == [1, 2]


def test_other_load_subtracts_this_process_and_commands_wait_passively_only_on_a_busy_machine(tmp_path, monkeypatch):
    hz = os.sysconf("SC_CLK_TCK")
    stat = tmp_path / "stat"
    clock = {"wall": 0.0, "own": 0.0, "busy": 1000 * hz, "others": 0.0}
    _stat(stat, clock["busy"])

    def sleep(seconds):  # this process sleeps; the others run
        clock["wall"] += seconds
        clock["busy"] += round(clock["others"] * seconds * hz)
        _stat(stat, clock["busy"])

    monkeypatch.setattr(threads.time, "sleep", sleep)
    monkeypatch.setattr(threads.time, "monotonic", lambda: clock["wall"])
    monkeypatch.setattr(threads.time, "process_time", lambda: clock["own"])
    monkeypatch.setattr(threads, "PROC_STAT", stat)
    clock["others"] = 1.0
    assert other_load(1.0, stat) == pytest.approx(1.0, abs=0.02)
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    clock["others"] = 0.1
    cli_main._choose_wait_policy("eval")
    assert "OMP_WAIT_POLICY" not in os.environ  # free: the runtime default
    clock["others"] = 1.0
    for command in ("train", "bench"):
        cli_main._choose_wait_policy(command)
        assert "OMP_WAIT_POLICY" not in os.environ  # training adapts its threads; benchmarks measure the default
    cli_main._choose_wait_policy("eval")
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    cli_main._choose_wait_policy("eval")
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"  # the user's own setting wins
