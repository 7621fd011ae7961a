"""calbench.mjcf — the shipped robot models (MJCF), installed as package data.

Not code: this file only makes the folder an importable package, so that
``importlib.resources.files("calbench.mjcf")`` finds the models in a plain install.
"""
