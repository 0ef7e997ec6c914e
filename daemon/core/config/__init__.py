"""The daemon's configuration: the TOML file and its embedded default (``default.toml``) ->
validated, frozen dataclasses (:mod:`grassd.daemon.core.config.settings`)."""
