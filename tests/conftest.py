"""``--compositing`` for the GL tests: tests taking the ``compositing`` fixture run once per listed
path (default ``fetch,blend``: both forced; ``auto`` takes fetch where the driver has it).

The ``rasterizer`` fixture runs a test once with the fused CPU kernels and once with their pure-torch twin (the
rendering test modules use it for every test: ``pytestmark = pytest.mark.usefixtures("rasterizer")``)."""

from __future__ import annotations

import pytest

PATHS = ("auto", "fetch", "blend")


@pytest.fixture(params=["torch", "fused"])
def rasterizer(request: pytest.FixtureRequest):
    """Renders inside the test use this rasterizer (unless they name one)."""
    from particlesplat.rendering.choice import use_rasterizer

    with use_rasterizer(request.param):
        yield request.param


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
