"""Compute offload: the calibration's simulations on a Dask cluster (``[compute] scheduler``).

:mod:`.config` reads ``[compute]``; :mod:`.remote` picks the calibrator (here or on the cluster)
and :mod:`.remote_job` is what a worker runs; :mod:`.wire` is the checked wire format of jobs
and answers (no pickle) and :mod:`.dask_client` the mutually authenticated client. The
back-off of a run the cluster could not compute is the service's
(:mod:`grassd.daemon.core.runtime.compute_retry`): it depends on nothing here."""
