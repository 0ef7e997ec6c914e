"""The ``grassd`` command line (click): :func:`grassd.daemon.cli.main.main` and one module per
group of sub-commands."""
