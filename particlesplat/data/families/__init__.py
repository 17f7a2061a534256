"""Scene families: generators that write the common scene format (docs/dataset.md).

``robot``: robot-workspace scenes composed and rendered by MuJoCo from robosuite's asset files (the
``sim`` extra). Importing this package loads nothing heavy.
"""
