"""The operator's view of the running daemon: its status as one declared type with its JSON
form (:mod:`.status_types`; each JSON object's keys as a TypedDict in :mod:`.status_json`, the
control socket's wire format), its health level (ok, degraded, failed), the Prometheus metrics
textfile, the alert command on health changes, the static status page and journald-ready
logging; :mod:`.operator_view` is what the service calls after runs and reconciles."""
