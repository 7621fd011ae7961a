"""calbench.scenarios — the shipped campaign files (TOML), installed as package data.

Not code: this file only makes the folder an importable package, so that
``importlib.resources.files("calbench.scenarios")`` finds them in a plain install. Their
``robot = "../mjcf/..."`` paths resolve the same in a checkout and in site-packages.
"""
