"""The ``particlesplat`` command: one module per subcommand and one dispatcher (:mod:`particlesplat.cli.main`)."""
