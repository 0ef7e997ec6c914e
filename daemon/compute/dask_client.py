"""grassd's client of a dask.distributed cluster: who it trusts and what it accepts.

Every grassd process that offloads simulations to Dask (the daemon's calibrations,
:mod:`grassd.daemon.compute.remote`; ``grassd sweep --scheduler``,
:mod:`grassd.daemon.offline.sweep`) connects through :func:`connect`:

- the scheduler is secured as ``[compute]`` requires (:func:`require_secured`): mutual TLS with
  the site's CA (:func:`security_of`), or, only with ``allow_insecure = true``, plain ``tcp://``
  with a warning; anything else is a :class:`~grassd.daemon.core.errors.ConfigError` saying how to
  fix it;
- the client sends and accepts Dask's ``msgpack`` serializer only (:data:`SERIALIZERS`), so a
  result a worker pickled is refused, never loaded;
- a finished task's answer is fetched with :func:`fetch_answer`, which turns what Dask raises
  into :class:`~grassd.daemon.core.errors.ComputeUnavailable` (the cluster could not run it) or
  :class:`~grassd.daemon.core.errors.ComputeResultRefused` (an answer not in msgpack's form).

The answer is then decoded by the caller's declared result type with
:func:`grassd.daemon.compute.wire.read_answer` and checked on arrival by the caller.
What Dask's protocol still unpickles is listed in docs/operating/compute.md.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from grassd.daemon.compute.config import ComputeConfig, security_problem
from grassd.daemon.core.errors import ComputeResultRefused, ComputeUnavailable, ConfigError

if TYPE_CHECKING:
    from distributed import Client, Future
    from distributed.security import Security

log = logging.getLogger(__name__)

#: the only Dask serialization family grassd's client sends and accepts (no pickle)
SERIALIZERS = ("msgpack",)

__all__ = ["SERIALIZERS", "connect", "fetch_answer", "require_secured", "security_of"]


def security_of(compute: ComputeConfig) -> Security | None:
    """The :class:`distributed.security.Security` of ``compute`` (mutual TLS with the site's
    CA: ``tls_ca_file``, ``tls_cert``, ``tls_key``), or None for a scheduler without TLS
    (``allow_insecure``)."""
    if not compute.uses_tls:
        return None
    from distributed.security import Security

    return Security(tls_ca_file=str(compute.tls_ca_file), tls_client_cert=str(compute.tls_cert),
                    tls_client_key=str(compute.tls_key), require_encryption=True)


def require_secured(compute: ComputeConfig, source: str | None, who: str = "this daemon"
                    ) -> None:
    """Check that ``compute.scheduler`` is secured as ``[compute]`` requires (see
    :func:`grassd.daemon.compute.config.security_problem`); a scheduler given another way
    than the config file (a command's ``--scheduler``) is checked here. ``source`` names the
    config file in the error; ``who`` is what a stranger could run code in (for the warning).
    Raises :class:`ConfigError` naming the key and the fix; logs a warning for a scheduler
    without TLS that ``allow_insecure`` admits."""
    if (problem := security_problem(compute)) is not None:
        raise ConfigError(problem[1], key=f"compute.{problem[0]}", path=source)
    if compute.scheduler is not None and not compute.uses_tls:
        log.warning("[compute] scheduler %s has no TLS (allow_insecure = true): anyone "
                    "who can reach it can run code in %s; use tls:// with the "
                    "site's CA (docs/operating/compute.md)", compute.scheduler, who)


def connect(compute: ComputeConfig) -> Client:
    """A :class:`distributed.Client` of ``compute.scheduler`` (checked with
    :func:`require_secured` first), with the site's TLS and the msgpack serializer only;
    ``connect_timeout_s`` [s] bounds the connection. The caller closes it. Raises
    :class:`ComputeUnavailable` when dask.distributed is missing or the scheduler cannot be
    reached or refuses the handshake."""
    if compute.scheduler is None:
        raise ValueError("connect needs [compute] scheduler")
    try:
        from distributed import Client
    except ImportError:
        raise ComputeUnavailable(
            "[compute] scheduler needs dask.distributed here: pip install "
            "'dask[distributed]'") from None
    try:
        return Client(compute.scheduler, timeout=compute.connect_timeout_s,
                      set_as_default=False, security=security_of(compute),
                      serializers=list(SERIALIZERS), deserializers=list(SERIALIZERS))
    except (OSError, ValueError) as exc:  # TimeoutError is an OSError
        raise ComputeUnavailable(
            f"cannot reach the Dask scheduler at {compute.scheduler} ({exc}); check that it "
            "runs, that [compute] scheduler names it and that its certificate is signed "
            "by [compute] tls_ca_file") from None


def fetch_answer(client: Client, fut: Future, address: str, worker: str | None = None
                 ) -> tuple[object, str | None]:
    """The finished task ``fut``'s answer as Dask's ``msgpack`` serializer read it (not yet
    checked: :func:`grassd.daemon.compute.wire.read_answer` reads it), and the
    worker that held it (``worker`` when already known, else the scheduler's ``who_has``).
    Raises :class:`ComputeUnavailable` for a worker Dask gave up on or a dropped connection,
    :class:`ComputeResultRefused` for a task that raised or an answer Dask could not read in
    that form (a pickle: it is never loaded)."""
    from distributed import KilledWorker

    try:
        if worker is None:  # finished before anyone looked: the worker holding it
            holders = client.who_has([fut]).get(fut.key, ())
            worker = holders[0] if holders else None
        return fut.result(), worker
    except KilledWorker as exc:
        raise ComputeUnavailable(f"the Dask workers at {address} died running the "
                                 f"task ({exc})") from None
    except (OSError, ValueError) as exc:  # the connection dropped
        raise ComputeUnavailable(f"lost the Dask scheduler at {address} while "
                                 f"fetching the result ({exc})") from None
    except Exception as exc:  # the task raised, or its answer is not msgpack
        raise ComputeResultRefused(
            f"Dask worker {worker or '(unknown)'} of {address} gave no answer "
            f"in the declared form ({type(exc).__name__}: {str(exc)[:300]})") from None
