"""calbench.studies — the shipped example studies (TOML, `calbench study`), installed as package data.

Not code: this file only makes the folder an importable package, so that
``importlib.resources.files("calbench.studies")`` finds them in a plain install. Their
``scenario = "../scenarios/..."`` paths resolve the same in a checkout and in site-packages.
"""
