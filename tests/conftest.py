"""``--compositing`` for the GL tests: tests taking the ``compositing`` fixture run once per listed
path (default ``fetch,blend``: both forced; ``auto`` takes fetch where the driver has it)."""

from __future__ import annotations

import pytest

PATHS = ("auto", "fetch", "blend")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--compositing",
        default="fetch,blend",
        help="comma-separated compositing paths of the GL tests, from auto, fetch, blend (default: %(default)s)",
    )


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "compositing" in metafunc.fixturenames:
        paths = [p.strip() for p in metafunc.config.getoption("compositing").split(",") if p.strip()]
        bad = [p for p in paths if p not in PATHS]
        if bad or not paths:
            raise pytest.UsageError(f"--compositing: expected paths from {PATHS}, got {bad or paths}")
        metafunc.parametrize("compositing", paths, scope="module")
