"""The ``[compute]`` config section: the daemon's simulations on a dask.distributed cluster.

::

    [compute]
    scheduler = "tls://calib-server:8786"   # absent: simulate here (needs grassd[sim])
    tls_ca_file = "/etc/grassd/dask/ca.pem" # the site's own CA: it signed the scheduler's,
                                            #   every worker's and this daemon's certificate
    tls_cert = "/etc/grassd/dask/grassd.pem"  # this daemon's client certificate and key
    tls_key = "/etc/grassd/dask/grassd.key"   #   (PEM; readable by the service user only)
    allow_insecure = false                  # true: a tcp:// (ws://, ucx://) scheduler without
                                            #   TLS is accepted, with a warning at each start
    connect_timeout_s = 10.0                # unreachable for this long, or no worker for
    worker_wait_s = 60.0                    #   worker_wait_s (s): the bundle waits, retried

Dask's own protocol unpickles what it receives, so whoever may join the cluster may run code in
the daemon: ``tls://`` with the site's CA (mutual TLS, :class:`distributed.security.Security`)
is the trust boundary, and plain ``tcp://`` is refused unless ``allow_insecure = true`` says
the network itself is trusted (see docs/operating/compute.md).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from grassd.daemon.core.config import schema

#: the address forms of a dask.distributed scheduler: protocol://host:port
_SCHEDULER_RE = re.compile(r"^(tcp|tls|ws|wss|ucx)://([^\s/:]+|\[[0-9A-Fa-f:.]+\]):\d{1,5}$")
#: the protocols that carry Dask's messages inside TLS
TLS_PROTOCOLS = ("tls", "wss")
#: the keys that name the TLS files, in the order they are documented
TLS_KEYS = ("tls_ca_file", "tls_cert", "tls_key")


@dataclass(frozen=True)
class ComputeConfig:
    """Where the daemon's calibrations are simulated (:mod:`grassd.daemon.compute.remote`):
    ``scheduler`` None here (needs Taichi, ``grassd[sim]``), else the address of a
    dask.distributed scheduler (``"tls://host:8786"``) whose workers have ``grassd[sim]``.
    ``tls_ca_file``, ``tls_cert``, ``tls_key``: the site CA's certificate and this daemon's
    client certificate and key (PEM files), required by a ``tls://`` / ``wss://`` scheduler;
    ``allow_insecure``: a scheduler without TLS is accepted only when true.
    ``connect_timeout_s`` [s]: how long connecting to it may take; ``worker_wait_s`` [s]: how
    long a run waits while the cluster has no worker. Either failing defers the bundle."""

    scheduler: str | None = None
    tls_ca_file: Path | None = None
    tls_cert: Path | None = None
    tls_key: Path | None = None
    allow_insecure: bool = False
    connect_timeout_s: float = 10.0
    worker_wait_s: float = 60.0

    @property
    def uses_tls(self) -> bool:
        """Whether ``scheduler`` is reached over TLS (``tls://`` or ``wss://``)."""
        return self.scheduler is not None and protocol_of(self.scheduler) in TLS_PROTOCOLS


def protocol_of(address: str) -> str:
    """The protocol of a scheduler address ("tls" of ``tls://host:8786``)."""
    return address.split("://", 1)[0]


def scheduler_address_problem(v: str) -> str | None:
    """What is wrong with ``v`` as a Dask scheduler address (``[compute] scheduler``,
    ``grassd calibrate --scheduler``), or None when it is one."""
    if _SCHEDULER_RE.match(v):
        return None
    return (f"must be a Dask scheduler address such as \"tls://host:8786\" (protocol tls, tcp, "
            f"wss, ws or ucx, then host:port), got {v!r}")


def security_problem(c: ComputeConfig) -> tuple[str, str] | None:
    """What is wrong with how ``c`` secures its scheduler, as (key, message telling the fix),
    or None: a ``tls://`` scheduler needs all three TLS files, one without TLS needs
    ``allow_insecure = true`` and no TLS files (they would not be used)."""
    if c.scheduler is None:
        return None
    given = [k for k in TLS_KEYS if getattr(c, k) is not None]
    if c.uses_tls:
        missing = [k for k in TLS_KEYS if k not in given]
        if missing:
            return (missing[0], f"a {protocol_of(c.scheduler)}:// scheduler needs "
                    f"{', '.join(TLS_KEYS)} (the site CA's certificate and this daemon's "
                    f"client certificate and key, PEM); missing: {', '.join(missing)}")
        return None
    if not c.allow_insecure:
        return ("scheduler", f"{c.scheduler} has no TLS: anyone who can reach it can join the "
                "cluster and run code in this daemon. Use tls://host:port with tls_ca_file, "
                "tls_cert and tls_key (docs/operating/compute.md), or, on a network you trust "
                "with that, set allow_insecure = true")
    if given:
        return (given[0], f"{given[0]} is set but {c.scheduler} is not a tls:// address; use "
                "tls:// or remove the TLS files")
    return None


def parse_compute(top: schema.Section, resolve: Callable[[schema.Context, str], Path]
                  ) -> ComputeConfig:
    """``[compute]`` of the configuration ``top``: the scheduler address (absent: simulate
    here), its TLS files (resolved with ``resolve``, relative to the config file; each must be
    a file), ``allow_insecure`` and the timeouts [s]. Raises the configuration's error naming
    the key and how to fix it."""
    d = top.section("compute", schema.schema(
        ComputeConfig, scheduler=schema.Field(str, check=scheduler_address_problem),
        tls_ca_file=schema.Field(str, check=schema.non_empty),
        tls_cert=schema.Field(str, check=schema.non_empty),
        tls_key=schema.Field(str, check=schema.non_empty),
        allow_insecure=schema.Field(bool),
        connect_timeout_s=schema.Field(float, check=schema.between(0.1, 3600.0, " s")),
        worker_wait_s=schema.Field(float, check=schema.between(0.0, 86400.0, " s")),
    ))
    files: dict[str, Path | None] = {}
    for key in TLS_KEYS:
        written = d.get_opt_str(key)
        files[key] = file = None if written is None else resolve(d.ctx, written)
        if file is not None and not file.is_file():
            raise d.error(key, f"{file} is not a file (PEM): make the "
                          "certificates with the site's CA (docs/operating/compute.md)")
    c = ComputeConfig(scheduler=d.get_opt_str("scheduler"), tls_ca_file=files["tls_ca_file"],
                      tls_cert=files["tls_cert"], tls_key=files["tls_key"],
                      allow_insecure=d.get_bool("allow_insecure"),
                      connect_timeout_s=d.get_float("connect_timeout_s"),
                      worker_wait_s=d.get_float("worker_wait_s"))
    if (problem := security_problem(c)) is not None:
        raise d.error(problem[0], problem[1])
    return c
