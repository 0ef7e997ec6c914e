"""The grassd daemon, one subpackage per role: ``config`` (settings), ``store`` (on-disk state),
``hardware`` (controllers, lux sensor, simulated stand-ins), ``calibration`` (runs),
``runtime`` (the service), ``offline`` (validation, experiments, sweeps) and ``cli``; the
docs/architecture.md says what depends on what."""
