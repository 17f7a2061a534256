"""Evaluation and figures: metrics, ``eval``, layer renders and turntables, particles as arrays."""
