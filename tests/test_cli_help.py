"""Every command's --help says each option's default at most once, and never "(default: None)"."""

from __future__ import annotations

import re

import pytest

from particlesplat.cli.main import COMMANDS, main

SUBCOMMANDS = {
    "object": ("export", "insert"),
    "scene": ("check",),
    "model": ("set",),  # model info: no options
    "policy": ("collect", "train", "eval"),
}


@pytest.mark.parametrize(
    "argv",
    [[c] for c in COMMANDS if c != "bench" and c not in SUBCOMMANDS]
    + [[c, sub] for c, subs in SUBCOMMANDS.items() for sub in subs],
)
def test_help_states_each_default_once(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main([*argv, "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert "(default: None)" not in " ".join(text.split())
    options = re.split(r"\n  (?=-)", text)  # one block per option
    assert len(options) > 2
    for block in options:
        said = len(re.findall(r"\bdefault\b", " ".join(block.split()), flags=re.IGNORECASE))
        assert said <= 1, block


def test_bench_without_registered_benchmarks_says_to_install(monkeypatch, capsys):
    """Benchmarks are entry points, registered by installing: a checkout run without installing has none."""
    import particlesplat.cli.main as cli_main

    monkeypatch.setattr(cli_main, "entry_points", lambda group: [])
    assert main(["bench", "train"]) == 2
    err = capsys.readouterr().err
    assert "no benchmarks are registered" in err and "pip install -e ." in err and err.count("\n") == 1


def test_bench_lists_the_benchmarks_of_the_library_and_the_viewer(capsys):
    assert main(["bench", "--help"]) == 0
    listed = capsys.readouterr().out.split("benchmarks:")[1].split()
    assert {"edits", "encode", "render", "train", "viewer"} <= set(listed)


def test_bench_edits_help_states_each_default_once(capsys):
    from particlesplat.bench.edits import main as bench_edits

    with pytest.raises(SystemExit) as e:
        bench_edits(["--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: None)" not in text and "(default: 12)" in text  # --scenes keeps its default
