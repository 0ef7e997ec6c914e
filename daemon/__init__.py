"""The grassd daemon, one subpackage per role: ``config`` (settings), ``store`` (on-disk state),
``hardware`` (controllers, lux sensor, simulated stand-ins), ``calibration`` (runs),
``runtime`` (the service), ``offline`` (validation, experiments, sweeps) and ``cli``; the
README's "The source tree" says what depends on what."""
