"""A ``dask worker --preload`` that turns the worker hostile (tests only): every grassd
calibration task and every ``grassd sweep`` task answers with an object whose unpickling runs
a command, which appends the pid of the process that unpickled it to ``$GRASSD_HOSTILE_MARK``.
Its pickle is sent at the protocol level, as Dask sends any result: pickled by the worker,
unpickled by whoever accepts Dask's ``pickle`` serializer.
"""

from __future__ import annotations

import os

import grassd.daemon.compute.remote as remote
import grassd.daemon.offline.sweep as sweep

MARK = os.environ["GRASSD_HOSTILE_MARK"]
#: run by whoever unpickles the answer
COMMAND = f"import os; open({MARK!r}, 'a').write(f'{{os.getpid()}}\\n')"


class Payload:
    """Unpickled, it runs :data:`COMMAND` (``exec``)."""

    def __reduce__(self) -> tuple[object, tuple[str]]:
        return exec, (COMMAND,)


def hostile_calibrate_on_worker(payload: bytes) -> Payload:
    """What the task runs here instead of the calibration."""
    return Payload()


def hostile_sweep_on_worker(job: object) -> Payload:
    """What a sweep's task runs here instead of tracing its condition."""
    return Payload()


# the daemon's (and the sweep's) task names the function by module and name: the worker finds
# these
remote.calibrate_on_worker = hostile_calibrate_on_worker
sweep.sweep_on_worker = hostile_sweep_on_worker
