"""Bundled data: the shipped models, the recipes that train them and the demo scenes (installed as
`particlesplat.assets`)."""
