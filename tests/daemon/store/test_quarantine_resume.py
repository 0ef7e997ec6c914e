"""Putting a quarantined bundle back is resumable: a crash after its directory went to
``inbox/.retry-<id>`` (step 1) or after its journal row was dropped (step 2) leaves it listed,
and running the retry again completes it. A namesake in the inbox is refused."""

from __future__ import annotations

import pytest
from daemon_harness import drop

from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Inbox
from grassd.daemon.core.store.quarantine import (
    RETRY_PREFIX,
    BundleRetryError,
    quarantined,
    retry_bundle,
)


def _abandoned(tmp_path, name: str) -> tuple[Inbox, str]:
    h = History(tmp_path / "state" / "state.db")
    inbox = Inbox(tmp_path / "inbox", tmp_path / "state", h, settle_s=0)
    drop(inbox.inbox, name)
    [b] = inbox.poll()
    for _ in range(3):  # three daemons killed while running it
        inbox.begin(b)
    assert inbox.recover() == []  # the next start quarantines it
    [q] = quarantined(h, inbox.inbox, inbox.state_dir)
    assert q.bundle == b.id and q.attempts == 3
    return inbox, b.id


@pytest.mark.parametrize("crash_after", ["move", "journal"])
def test_an_interrupted_retry_is_listed_and_completes(tmp_path, crash_after):
    inbox, bid = _abandoned(tmp_path, "b1")
    staged = inbox.inbox / f"{RETRY_PREFIX}{bid}"
    (inbox.rejected / bid).rename(staged)  # step 1 done, then the power went
    if crash_after == "journal":
        [j] = inbox.history.journal("rejected")
        inbox.history.journal_forget(j.bundle_hash, state="rejected")
    assert inbox.poll() == []  # the daemon ignores the hidden directory
    [q] = quarantined(inbox.history, inbox.inbox, inbox.state_dir)
    assert q.bundle == bid
    out = retry_bundle(inbox, bid)
    assert out["inbox_path"] == str(inbox.inbox / "b1")
    assert not staged.exists() and inbox.history.journal() == []
    [b] = inbox.poll()  # claimed as a new upload, first attempt
    assert inbox.begin(b) == 1
    inbox.history.close()


def test_retry_refuses_a_namesake_in_the_inbox_and_an_unknown_name(tmp_path):
    inbox, bid = _abandoned(tmp_path, "b1")
    drop(inbox.inbox, "b1", lux=1234.0)  # a new upload of the same name waits there
    with pytest.raises(BundleRetryError, match="already holds a bundle named 'b1'"):
        retry_bundle(inbox, "b1")
    assert (inbox.rejected / bid).is_dir()  # nothing moved
    with pytest.raises(BundleRetryError, match="no quarantined bundle 'b2'"):
        retry_bundle(inbox, "b2")
    inbox.history.close()
