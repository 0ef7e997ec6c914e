"""The grassd daemon: config, ingest, scheduling, orchestration, history, control socket, CLI."""
