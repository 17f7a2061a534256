"""File formats: 3DGS ``.ply`` and PNG with text chunks."""
