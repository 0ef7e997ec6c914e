"""``python -m grassd.daemon.cli``: the ``grassd`` command without its console script."""

from grassd.daemon.cli.main import main

main()
