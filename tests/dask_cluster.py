"""The Dask cluster of :mod:`grassd.rigs.dask_cluster` for tests: a test on a machine that
cannot run it (no ``dask`` command, no openssl) is skipped with the rig's reason; and
:func:`tampered`, an honest answer altered as a worker would."""

from __future__ import annotations

from pathlib import Path

import pytest

from grassd.rigs import dask_cluster as rig
from grassd.rigs.dask_cluster import free_port

__all__ = ["DaskCluster", "SiteCA", "free_port", "tampered"]


class SiteCA(rig.SiteCA):
    """:class:`grassd.rigs.dask_cluster.SiteCA`, skipping the test without openssl."""

    def __init__(self, directory: Path, name: str = "grassd-test-ca") -> None:
        try:
            super().__init__(directory, name)
        except rig.ClusterUnavailable as exc:
            pytest.skip(str(exc))


class DaskCluster(rig.DaskCluster):
    """:class:`grassd.rigs.dask_cluster.DaskCluster`, skipping the test where it cannot run."""

    def __init__(self, logs: Path, cache_dir: str | None = None, tls: bool = True) -> None:
        try:
            super().__init__(logs, cache_dir, tls)
        except rig.ClusterUnavailable as exc:
            pytest.skip(str(exc))


def tampered(wire: dict, change) -> dict:
    """A copy of a decoded msgpack answer ``wire`` (tuples for lists, as msgpack gives them
    back with ``use_list=False``) in plain lists and dicts, with ``change`` applied to its
    ``result``: what a worker that altered an honest answer sends."""
    def thawed(v):
        if isinstance(v, dict):
            return {k: thawed(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [thawed(x) for x in v]
        return v

    out = thawed(wire)
    change(out["result"])
    return out
