"""The test command's summary names each skipped group, how many tests it holds, where, and why (the reason says
what runs them), so a skipped group is never read as a passed one."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

from conftest import skipped_groups

ROOT = Path(__file__).resolve().parents[1]


def test_skipped_reports_group_by_reason():
    def report(nodeid: str, reason: str):
        return SimpleNamespace(nodeid=nodeid, longrepr=(nodeid.split("::")[0], 1, f"Skipped: {reason}"))

    sim = "robot scenes need the sim extra: pip install mujoco && pip install --no-deps robosuite==1.5.2"
    reports = [
        report("tests/test_robot_scenes.py::a", sim),
        report("tests/test_robot_scenes.py::b", sim),
        report("tests/test_bench_edits.py::c", sim),
        report("tests/test_cuda.py::d", "needs a CUDA GPU"),
    ]
    assert skipped_groups(reports) == [
        (sim, 3, ["tests/test_bench_edits.py", "tests/test_robot_scenes.py"]),
        ("needs a CUDA GPU", 1, ["tests/test_cuda.py"]),
    ]


def test_the_summary_is_printed(tmp_path):
    """A run with a skipped test prints the 'skipped groups' section with its reason (this suite's conftest)."""
    (tmp_path / "conftest.py").write_text((ROOT / "tests" / "conftest.py").read_text())
    (tmp_path / "test_x.py").write_text(
        textwrap.dedent(
            """
            import pytest

            @pytest.mark.skip(reason="needs the sim extra: pip install -e '.[sim]'")
            def test_a():
                pass

            def test_b():
                pass
            """
        )
    )
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "skipped groups" in proc.stdout
    assert "1 test(s) in test_x.py: needs the sim extra: pip install -e '.[sim]'" in proc.stdout, proc.stdout
