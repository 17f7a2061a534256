"""The ``particlesplat`` command: subcommands are loaded lazily from their own modules.

Each subcommand module defines ``add_arguments(parser)`` and ``run(args) -> int``.
Benchmarks are found through the ``particlesplat.bench`` entry-point group, so the library
never imports the viewer itself.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from importlib.metadata import entry_points

from particlesplat.core.options import HelpFormatter, attach_option_values

__all__ = ["COMMANDS", "HelpFormatter", "console_main", "main"]

COMMANDS: dict[str, tuple[str, str]] = {
    "synth": ("particlesplat.cli.synth", "generate a scene dataset"),
    "train": ("particlesplat.cli.train", "train a ParticleSplat model"),
    "eval": ("particlesplat.cli.eval", "evaluate a model on a folder of scenes, or on each split of a dataset"),
    "render": ("particlesplat.cli.render", "render a (possibly edited) scene headless to PNG"),
    "export": ("particlesplat.cli.export", "write a (possibly edited) scene as .ply/.splat/.spz/.sog, or a bundle"),
    "encode": ("particlesplat.cli.encode", "write the particles of scene folders as .npz arrays"),
    "object": ("particlesplat.cli.object", "export an object to .ply, or insert it into another scene"),
    "curve": ("particlesplat.cli.curve", "plot the validation curves of training runs to PNG"),
    "model": ("particlesplat.cli.model", "show a checkpoint, or copy it with inference keys changed"),
    "scene": ("particlesplat.cli.scene", "check a scene folder's world frame (+z up, support at z = 0, metres)"),
    "policy": ("particlesplat.cli.policy", "robot tasks: record demonstrations, train and evaluate policies"),
    "bench": ("", "run a benchmark: " + ", ".join(sorted(e.name for e in entry_points(group="particlesplat.bench")))),
}


def _top_help() -> str:
    lines = [
        "usage: particlesplat <command> [options]",
        "",
        "ParticleSplat Studio: object-centric latent particles decoded into 3D Gaussians.",
        "",
        "commands:",
    ]
    lines += [f"  {name:<8} {desc}" for name, (_, desc) in COMMANDS.items()]
    lines += ["", "Run 'particlesplat <command> --help' for a command's options."]
    return "\n".join(lines)


def _run_bench(argv: list[str]) -> int:
    benches = {e.name: e for e in entry_points(group="particlesplat.bench")}
    if not benches:  # they are registered by installing (entry points): a bare checkout has none
        print(
            "particlesplat bench: no benchmarks are registered: install ParticleSplat Studio "
            "(pip install -e . in its checkout)",
            file=sys.stderr,
        )
        return 2
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: particlesplat bench <name> [options]\n\nbenchmarks:")
        for name in sorted(benches):
            print(f"  {name}")
        print("\nRun 'particlesplat bench <name> --help' for its options.")
        return 0
    if argv[0] not in benches:
        print(
            f"particlesplat bench: unknown benchmark '{argv[0]}' (have: {', '.join(sorted(benches))})", file=sys.stderr
        )
        return 2
    return int(benches[argv[0]].load()(argv[1:]) or 0)


def _choose_wait_policy(command: str) -> None:
    """OpenMP threads of a command started on a machine whose cores other work keeps busy wait passively (set
    before torch loads its OpenMP runtime; the user's own ``OMP_WAIT_POLICY`` wins). Training spins instead and
    lowers its thread count while the cores are busy (``train.adapt_threads``): spinning on free cores made a robot
    step 1.54 s against 2.57 s waiting passively (:mod:`particlesplat.core.threads`). Benchmarks measure the
    runtime's default unless the user sets the policy."""
    from particlesplat.core.threads import wait_policy_for_load

    if command in ("train", "bench") or "OMP_WAIT_POLICY" in os.environ:  # benchmarks: the runtime default
        return
    policy = wait_policy_for_load()
    if policy is not None:
        os.environ["OMP_WAIT_POLICY"] = policy


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_top_help())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"particlesplat: unknown command '{name}'\n\n{_top_help()}", file=sys.stderr)
        return 2
    _choose_wait_policy(name)
    from particlesplat.core.threads import bound_thread_variables

    bound_thread_variables()  # before torch reads them
    if name == "bench":
        return _run_bench(rest)
    module = importlib.import_module(COMMANDS[name][0])
    parser = argparse.ArgumentParser(
        prog=f"particlesplat {name}",
        description=COMMANDS[name][1],
        formatter_class=HelpFormatter,
    )
    module.add_arguments(parser)
    args = parser.parse_args(attach_option_values(rest))  # --look -30,20,3: a negative azimuth
    return int(module.run(args) or 0)


def console_main() -> int:
    """The console script under the error policy (:func:`particlesplat.core.errors.run_command`): bad input
    (ValueError, OSError) ends with one line naming the file and the field and exit code 2, Ctrl-C with one
    line and 130, SIGTERM as Ctrl-C with 143 (:func:`particlesplat.core.errors.stop_on_sigterm`); a bug keeps its
    traceback. :func:`main` itself lets the exceptions through for programmatic
    use and tests.
    """
    from particlesplat.core.errors import end_at_once_if_interrupted, one_line, run_command, stop_on_sigterm

    stop_on_sigterm()  # SIGTERM is Ctrl-C for every command: temporary files removed, one line, exit 143
    command = one_line(sys.argv[1], 40) if len(sys.argv) > 1 else ""
    return end_at_once_if_interrupted(run_command(f"particlesplat {command}".strip(), main))
