"""The running daemon: the service's main loop (bundle pipeline, commit, reconcile, status), its
control socket, systemd notification, the state directory's lock and retention."""
