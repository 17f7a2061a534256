"""Bundled data: the trained model, its config and demo scenes (installed as `particlesplat.assets`)."""
