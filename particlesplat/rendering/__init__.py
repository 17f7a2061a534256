"""The differentiable torch Gaussian renderer: EWA projection, tiled rasterizer, dense reference, ``render``."""
