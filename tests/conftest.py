"""``--compositing`` for the GL tests: tests taking the ``compositing`` fixture run once per listed
path (default ``fetch,blend``: both forced; ``auto`` takes fetch where the driver has it).

The ``rasterizer`` fixture runs a test once with the fused CPU kernels and once with their pure-torch twin (the
rendering test modules use it for every test: ``pytestmark = pytest.mark.usefixtures("rasterizer")``).

The ``window`` fixture is the one real window the in-process app tests share."""

from __future__ import annotations

import contextlib
import io
import os

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


@pytest.fixture(scope="session", autouse=True)
def _measured_rasterizer(tmp_path_factory: pytest.TempPathFactory) -> None:
    """``rasterizer: auto`` measured once for the whole run (a few seconds), in a cache folder of the run's own that
    every test and the commands they start read (``$XDG_CACHE_HOME`` is inherited): no test measures again or
    prints the measurement's line, and the user's own cache is never touched."""
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("xdg_cache"))
    import particlesplat.rendering.api  # noqa: F401  (registers the renderer the measurement times)
    from particlesplat.rendering.measured import measured_choice

    with contextlib.redirect_stderr(io.StringIO()):
        measured_choice(False)


@pytest.fixture(scope="session")
def window():
    """One glfw window and its moderngl context for every in-process app test of the run (moderngl detects a
    window's context once, and a process cannot open a GL window again after closing one on EGL)."""
    import moderngl

    from viewer import app

    if not os.environ.get("DISPLAY"):
        pytest.fail("no DISPLAY: run the tests under xvfb-run (see the README's test command)")
    w = app.create_window((160, 120))
    yield w, moderngl.create_context()
    app.destroy_window(w)


@pytest.fixture(autouse=True)
def _user_folders(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """The user's XDG folders (autosaves, settings, outputs) in a temporary folder: a test never writes to the
    home folder of whoever runs the suite."""
    home = tmp_path_factory.mktemp("xdg")
    for name in ("XDG_STATE_HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME"):
        monkeypatch.setenv(name, str(home / name.lower()))


def skipped_groups(reports: list) -> list[tuple[str, int, list[str]]]:
    """(reason, number of tests, their files) of skipped test reports, most tests first."""
    groups: dict[str, tuple[int, set[str]]] = {}
    for r in reports:
        if isinstance(r.longrepr, tuple) and len(r.longrepr) == 3:  # (file, line, "Skipped: reason")
            reason = str(r.longrepr[2]).removeprefix("Skipped: ")
        else:
            reason = str(r.longrepr)
        count, files = groups.get(reason, (0, set()))
        groups[reason] = (count + 1, files | {r.nodeid.split("::")[0]})
    return sorted(((k, n, sorted(f)) for k, (n, f) in groups.items()), key=lambda g: -g[1])


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    """Which groups of tests were skipped and why (the reason says what runs them: an extra to install, a GPU,
    a variable to set), so a skipped group is never mistaken for a passed one."""
    groups = skipped_groups(terminalreporter.stats.get("skipped", []))
    if not groups:
        return
    terminalreporter.section("skipped groups")
    for reason, count, files in groups:
        terminalreporter.write_line(f"{count} test(s) in {', '.join(files)}: {reason}")
