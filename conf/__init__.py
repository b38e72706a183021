"""The config groups' YAML, shipped as the package ``dqn_transfer.conf`` (pyproject.toml maps ``conf/`` to it).

This file makes ``conf/`` a regular package: setuptools' editable install finds a mapped package only if it
has an ``__init__.py`` (a directory without one is not importable there). Hydra skips it when it lists groups.
"""
