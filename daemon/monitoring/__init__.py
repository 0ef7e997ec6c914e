"""The operator's view of the running daemon: its health level (ok, degraded, failed), the
Prometheus metrics textfile, the alert command on health changes, the static status page and
journald-ready logging; :mod:`.operator_view` is what the service calls after runs and
reconciles."""
