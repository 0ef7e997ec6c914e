"""Root never reads, as root, what another user may change in a state directory.

The service's state directory belongs to its user (``StateDirectory=``, user ``grassd``), which
writes everything in it: the history database, the tables, the measurements, the archived
bundles. A command started by root that reads it (``grassd studio --state-dir``, ``grassd
calibrate --now``, ``grassd measure --now``, ``status``, ``history``, ``bundles``, ``capture``,
``controllers``, ``run``) therefore first becomes that user: its uid, its account's group and
supplementary groups (``dialout`` for the serial ports), its ``$HOME``; what it writes there
stays the owner's. Where root owns the state directory, the command stays root, but refuses
(:class:`~grassd.daemon.core.errors.OthersMayWrite`) if another user may change the directory, a
directory above it or anything in it but the bundles (the inbox, ``processing/``,
``archive/``, ``rejected/``: hostile input wherever it lies, read with the inbox's checks).
Either way, root refuses a configuration file that another user may change. The rule is
:mod:`grassd.sim.path_trust`'s, as for the kernel cache.
"""

from __future__ import annotations

import os
import pwd
from pathlib import Path

import click

from grassd.daemon.core.config.settings import Config, resolve_config
from grassd.daemon.core.errors import OthersMayWrite, OwnerUnknown, SwitchUserFailed
from grassd.daemon.core.store.layout import StateLayout
from grassd.sim.path_trust import Untrusted, owner_name, untrusted_below, untrusted_part

__all__ = ["config_as_state_owner", "become_state_owner"]

#: Environment variables of root's session that name root's own directories: dropped when
#: the process becomes another user, whose defaults then apply (``~/.cache`` and so on).
_ROOTS_DIRS = ("XDG_CACHE_HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_STATE_HOME",
               "XDG_RUNTIME_DIR")


def _bundle_dirs(cfg: Config) -> set[Path]:
    """The directories whose contents are bundles (hostile input, checked as it is read)."""
    layout = StateLayout(cfg.state_dir)
    return {cfg.light.inbox, layout.processing, layout.archive, layout.rejected}


def _fault_in_tree(cfg: Config) -> Untrusted | None:
    """The first part of root's own state directory that another user may change: the
    directory and those above it, then every entry below it but the bundles' contents."""
    root = cfg.state_dir
    if (fault := untrusted_part(root, 0)) is not None:
        return fault
    return untrusted_below(root, 0, frozenset(_bundle_dirs(cfg)))


def _config_file(cfg: Config) -> Path | None:
    """The configuration file ``cfg`` came from (None for the embedded default)."""
    return None if cfg.source.startswith("<") else Path(cfg.source)


def become_state_owner(cfg: Config, command: str) -> int | None:
    """As root, for ``command`` (its name, for messages) about to read ``cfg.state_dir``:
    become the directory's owner where another user owns it and return that uid; refuse
    (:class:`~grassd.daemon.core.errors.RootRefuses`) a state directory or configuration of root's
    that another user may change. None where nothing changed (not root, root's own
    directory, or one that does not exist yet: root creates it)."""
    if os.geteuid() != 0:
        return None
    conf = _config_file(cfg)
    if conf is not None and (fault := untrusted_part(conf, 0)) is not None:
        raise OthersMayWrite(
            f"{command} started by root reads the configuration {conf}, but {fault}: another "
            f"user could make root run anything (alert commands, paths). Make it root's and "
            f"not writable by others (chown root {conf}; chmod go-w {conf})")
    try:
        owner = os.stat(cfg.state_dir).st_uid
    except FileNotFoundError:
        owner = 0
    if owner == 0:
        if (fault := _fault_in_tree(cfg)) is not None:
            raise OthersMayWrite(
                f"{command} started by root reads the state directory {cfg.state_dir}, but "
                f"{fault}: root would load what another user wrote. Run it as the user who "
                f"owns the files (sudo -u USER grassd ...), or give the directory to one user "
                f"(chown -R USER {cfg.state_dir}: root then runs as that user)")
        return None
    try:
        account = pwd.getpwuid(owner)
    except KeyError:
        raise OwnerUnknown(
            f"{command} started by root: the state directory {cfg.state_dir} belongs to uid "
            f"{owner}, which has no account here, so root cannot become it; run the command "
            f"as that uid, or chown the directory to the service's user") from None
    try:
        os.initgroups(account.pw_name, account.pw_gid)
        os.setgid(account.pw_gid)
        os.setuid(owner)
    except OSError as exc:
        raise SwitchUserFailed(
            f"{command} started by root could not become {owner_name(owner)}, the owner of "
            f"the state directory {cfg.state_dir}: {exc.strerror}; run it as that user "
            f"(sudo -u {account.pw_name} grassd ...)") from None
    for var in _ROOTS_DIRS:
        os.environ.pop(var, None)
    os.environ.update(HOME=account.pw_dir, USER=account.pw_name, LOGNAME=account.pw_name)
    click.echo(f"grassd {command}: runs as {owner_name(owner)}, the owner of {cfg.state_dir}, "
               f"not as root", err=True)
    return owner


def config_as_state_owner(config_path: str | os.PathLike[str] | None,
                          state_dir: str | os.PathLike[str] | None, command: str) -> Config:
    """:func:`~grassd.daemon.core.config.settings.resolve_config` for a command that reads the
    state directory: as root, first :func:`become_state_owner`, and the configuration
    resolved again as that user (its cache directory is its own)."""
    cfg = resolve_config(config_path, state_dir)
    if become_state_owner(cfg, command) is None:
        return cfg
    return resolve_config(config_path, state_dir)
