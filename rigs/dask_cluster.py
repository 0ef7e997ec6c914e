"""A real dask.distributed cluster on 127.0.0.1 for tests and benchmarks: a ``dask
scheduler`` process and ``dask worker`` processes (no nanny, so a killed worker stays dead),
each in its own process group, their output in log files. Workers get ``$GRASSD_CACHE_DIR``
(the tests' shared Taichi kernel cache) and one thread (Taichi uses every core itself).

    with DaskCluster(tmp_path) as cluster:      # starts the scheduler
        cluster.add_worker("w1")                # and a worker; cluster.address: tls://127.0.0.1:N
        ...                                     # [compute] as cluster.compute() / .toml()
        cluster.kill_worker("w1")               # SIGKILL, as a crash

The cluster speaks mutual TLS with a site CA of its own (:class:`SiteCA`, made with openssl in
the test's directory) unless ``tls=False`` (then plain tcp://, which the daemon takes only with
``allow_insecure``). :meth:`DaskCluster.hostile_preload` writes the preload that turns a
worker hostile (:data:`HOSTILE_PRELOAD`). Without the ``dask`` command or openssl,
:class:`ClusterUnavailable` says what to install.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from grassd.daemon.compute.config import ComputeConfig
from grassd.rigs.processes import end_process

DASK = Path(sys.executable).parent / "dask"
OPENSSL = shutil.which("openssl")

#: what a leaf certificate of the test CA may do (a scheduler, worker or client)
LEAF_EXT = """basicConstraints = critical, CA:FALSE
keyUsage = critical, digitalSignature, keyEncipherment
extendedKeyUsage = serverAuth, clientAuth
subjectAltName = IP:127.0.0.1, DNS:localhost
subjectKeyIdentifier = hash
authorityKeyIdentifier = keyid
"""


class ClusterUnavailable(RuntimeError):
    """This machine cannot run the cluster (no ``dask`` command, no openssl); the message says
    what to install."""


#: The text of a ``dask worker --preload`` that turns the worker hostile: every grassd
#: calibration task and every ``grassd sweep`` task answers with an object whose unpickling runs
#: a command, which appends the pid of the process that unpickled it to
#: ``$GRASSD_HOSTILE_MARK``. Its pickle is sent at the protocol level, as Dask sends any result:
#: pickled by the worker, unpickled by whoever accepts Dask's ``pickle`` serializer. It is text
#: written out by :meth:`DaskCluster.hostile_preload`, never a module of this package, so that
#: nothing can import it by mistake (nor can the daemon, as it cannot import an attacker's).
HOSTILE_PRELOAD = r'''"""Turns this dask worker hostile (rigs/dask_cluster.py)."""
import os

import grassd.daemon.compute.remote as remote
import grassd.daemon.offline.sweep as sweep

MARK = os.environ["GRASSD_HOSTILE_MARK"]
COMMAND = f"import os; open({MARK!r}, 'a').write(f'{{os.getpid()}}\\n')"


class Payload:
    """Unpickled, it runs COMMAND (exec)."""

    def __reduce__(self):
        return exec, (COMMAND,)


def hostile_calibrate_on_worker(payload):
    return Payload()


def hostile_sweep_on_worker(job):
    return Payload()


# the daemon's (and the sweep's) task names the function by module and name: the worker
# finds these
remote.calibrate_on_worker = hostile_calibrate_on_worker
sweep.sweep_on_worker = hostile_sweep_on_worker
'''


class SiteCA:

    """A certificate authority of its own (an EC P-256 key, valid one day) in ``directory``,
    and the leaf certificates it signs; :class:`ClusterUnavailable` without openssl."""

    def __init__(self, directory: Path, name: str = "grassd-test-ca") -> None:
        if OPENSSL is None:
            raise ClusterUnavailable("openssl is not installed (the cluster's TLS certificates "
                                     "are made with it): apt-get install openssl")
        self.dir = directory
        self.dir.mkdir(parents=True, exist_ok=True)
        self.ca_file, self.ca_key = self.dir / "ca.pem", self.dir / "ca.key"
        self._issued: set[str] = set()  # the names signed by this CA (not a former one)
        self._openssl("req", "-x509", "-newkey", "ec", "-pkeyopt",
                      "ec_paramgen_curve:prime256v1", "-nodes", "-keyout", self.ca_key,
                      "-out", self.ca_file, "-days", "1", "-subj", f"/CN={name}")

    def _openssl(self, *args: object) -> None:
        subprocess.run([OPENSSL, *map(str, args)], check=True, capture_output=True,
                       cwd=self.dir)

    def issue(self, name: str) -> tuple[Path, Path]:
        """A certificate and key for ``name`` signed by this CA: (cert.pem, key.pem)."""
        cert, key, csr = (self.dir / f"{name}.pem", self.dir / f"{name}.key",
                          self.dir / f"{name}.csr")
        if name not in self._issued:
            ext = self.dir / "leaf.ext"
            ext.write_text(LEAF_EXT)
            self._openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
                          "-nodes", "-keyout", key, "-out", csr, "-subj", f"/CN={name}")
            self._openssl("x509", "-req", "-in", csr, "-CA", self.ca_file, "-CAkey",
                          self.ca_key, "-CAcreateserial", "-out", cert, "-days", "1",
                          "-extfile", ext)
            self._issued.add(name)
        return cert, key

    def tls_args(self, name: str) -> list[str]:
        """``dask scheduler`` / ``dask worker`` options presenting ``name``'s certificate."""
        cert, key = self.issue(name)
        return ["--tls-ca-file", str(self.ca_file), "--tls-cert", str(cert), "--tls-key",
                str(key)]

    def security(self, name: str = "client") -> Any:
        """A :class:`distributed.security.Security` presenting ``name``'s certificate."""
        from distributed.security import Security

        cert, key = self.issue(name)
        return Security(tls_ca_file=str(self.ca_file), tls_client_cert=str(cert),
                        tls_client_key=str(key), require_encryption=True)


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DaskCluster:
    """A scheduler on a free port of 127.0.0.1 and the workers added to it (see the module
    docstring); :class:`ClusterUnavailable` where the ``dask`` command is not installed."""

    def __init__(self, logs: Path, cache_dir: str | None = None, tls: bool = True) -> None:
        if not DASK.exists():
            raise ClusterUnavailable(f"{DASK} is not installed: pip install "
                                     "'dask[distributed]' (make setup-test does)")
        self.logs = logs
        self.logs.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        #: the site CA of a TLS cluster (None: plain tcp://)
        self.ca = SiteCA(logs / "tls") if tls else None
        self.address = f"{'tls' if tls else 'tcp'}://127.0.0.1:{self.port}"
        self.env = dict(os.environ)
        if cache_dir is not None:
            self.env["GRASSD_CACHE_DIR"] = cache_dir
        self.scheduler: subprocess.Popen | None = None
        self.workers: dict[str, subprocess.Popen] = {}

    def _start(self, args: list[str], name: str) -> subprocess.Popen:
        with open(self.logs / f"{name}.log", "ab") as log:
            return subprocess.Popen([str(DASK), *args], stdout=log, stderr=subprocess.STDOUT,
                                    cwd=self.logs, env=self.env, start_new_session=True)

    def security(self, name: str = "client") -> Any:
        """What a client presents to this cluster (None without TLS)."""
        return None if self.ca is None else self.ca.security(name)

    def compute(self, **kw: Any) -> ComputeConfig:
        """``[compute]`` for this cluster: its address, and the daemon's TLS files (or
        ``allow_insecure`` without TLS); ``kw`` sets the other fields."""
        return ComputeConfig(scheduler=self.address, **self._security_fields(), **kw)

    def toml(self) -> str:
        """The ``[compute]`` keys of :meth:`compute` as TOML lines (no table header)."""
        lines = [f'scheduler = "{self.address}"']
        for k, v in self._security_fields().items():
            lines.append(f"{k} = true" if v is True else f'{k} = "{v}"')
        return "\n".join(lines) + "\n"

    def _security_fields(self) -> dict[str, Any]:
        if self.ca is None:
            return {"allow_insecure": True}
        cert, key = self.ca.issue("grassd")
        return {"tls_ca_file": self.ca.ca_file, "tls_cert": cert, "tls_key": key}

    def __enter__(self) -> DaskCluster:
        tls = [] if self.ca is None else ["--protocol", "tls", *self.ca.tls_args("scheduler")]
        self.scheduler = self._start(["scheduler", "--host", "127.0.0.1", "--port",
                                      str(self.port), "--no-dashboard", *tls], "scheduler")
        deadline = time.monotonic() + 30
        while True:
            if self.scheduler.poll() is not None:
                raise RuntimeError(f"dask scheduler exited with {self.scheduler.returncode}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.5):
                    return self
            except OSError:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"dask scheduler not listening on {self.port}") from None
                time.sleep(0.2)

    def start_worker(self, name: str, tls_args: list[str] | None = None,
                     extra: tuple[str, ...] = ()) -> subprocess.Popen:
        """Start worker ``name`` (``tls_args``: what it presents, by default a certificate of
        the cluster's CA; ``extra``: more ``dask worker`` options, e.g. a preload) without
        waiting for it to join."""
        if tls_args is None:
            tls_args = [] if self.ca is None else self.ca.tls_args(name)
        p = self._start(["worker", self.address, "--nthreads", "1", "--no-dashboard",
                         "--no-nanny", "--host", "127.0.0.1", "--death-timeout", "60",
                         "--name", name, *tls_args, *extra], f"worker-{name}")
        self.workers[name] = p
        return p

    def worker_pids(self) -> set[int]:
        """The pids of the workers the scheduler lists now."""
        from distributed import Client

        with Client(self.address, timeout=30, set_as_default=False,
                    security=self.security()) as client:
            return set(client.run(os.getpid).values())

    def add_worker(self, name: str, timeout_s: float = 60.0, extra: tuple[str, ...] = ()
                   ) -> int:
        """Start worker ``name`` and wait until the scheduler lists it; returns its pid."""
        from distributed import Client

        p = self.start_worker(name, extra=extra)
        with Client(self.address, timeout=30, set_as_default=False,
                    security=self.security()) as client:
            deadline = time.monotonic() + timeout_s
            while p.pid not in set(client.run(os.getpid).values()):
                assert p.poll() is None, f"dask worker {name} exited with {p.returncode}"
                assert time.monotonic() < deadline, f"dask worker {name} did not join"
                time.sleep(0.2)
        return p.pid

    def hostile_preload(self, mark: Path) -> str:
        """Write :data:`HOSTILE_PRELOAD` where the calling process cannot import it (the
        cluster's log folder) and return its path for ``--preload``; its command appends to
        ``mark`` (set in the workers' environment)."""
        self.env["GRASSD_HOSTILE_MARK"] = str(mark)
        path = self.logs / "attacker" / "hostile_preload.py"
        path.parent.mkdir(exist_ok=True)
        path.write_text(HOSTILE_PRELOAD)
        return str(path)

    def kill_worker(self, name: str) -> None:
        """SIGKILL worker ``name`` (a crash: no goodbye to the scheduler) and reap it."""
        p = self.workers.pop(name)
        os.killpg(p.pid, signal.SIGKILL)
        p.wait(10)

    def __exit__(self, *exc: object) -> None:
        for p in [*self.workers.values(), self.scheduler]:
            if p is not None:
                end_process(p, 10.0, group=True)
        self.workers.clear()

