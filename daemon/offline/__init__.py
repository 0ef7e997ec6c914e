"""A tool beside the running daemon, never on its ``grassd run`` path: validation against real
captures, fit (the pixel's materials), the paper's experiments, virtual captures, HTML reports,
sweeps and ``grassd simulate``, with their command groups (``*_cli.py``) and settings
(``fit_config.py``, ``sweep_config.py``)."""
