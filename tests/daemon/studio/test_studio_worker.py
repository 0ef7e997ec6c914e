"""The studio's job runner: one job at a time, and a newer job of the same owner supersedes
the older one, queued or running; other owners' jobs are not touched."""

from __future__ import annotations

import threading
from collections.abc import Callable

import pytest

from grassd.daemon.studio.worker import Check, Superseded, Worker


def held_job() -> tuple[threading.Event, threading.Event, Callable[[Check], str]]:
    """A job that signals ``started``, waits for ``release``, then checks (where a newer job
    or a cancel that came in meanwhile makes it raise)."""
    started, release = threading.Event(), threading.Event()

    def job(check: Check) -> str:
        started.set()
        release.wait(10)
        check()
        return "not reached"

    return started, release, job


def test_a_newer_job_of_the_same_owner_stops_the_running_one():
    w = Worker()
    started, release, long = held_job()
    first = w.submit("page", long)
    assert started.wait(10)
    queued = w.submit("page", lambda check: "queued, then replaced")
    other = w.submit("another page", lambda check: "other owner")
    newest = w.submit("page", lambda check: "newest")
    release.set()
    with pytest.raises(Superseded):
        first.result(10)
    with pytest.raises(Superseded):
        queued.result(10)
    assert other.result(10) == "other owner"
    assert newest.result(10) == "newest"
    assert w._latest == {} and w._queued == {}
    w.stop()


def test_cancel_stops_an_owners_jobs_and_errors_reach_the_future():
    w = Worker()
    gate = threading.Event()
    running = w.submit("page", lambda check: (gate.wait(10), check()))
    w.cancel("page")
    gate.set()
    with pytest.raises(Superseded):
        running.result(10)
    assert w._latest == {} and w._queued == {}  # nothing kept about finished owners
    failing = w.submit("api", lambda check: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        failing.result(10)
    w.stop()


def test_cancel_all_stops_every_owners_running_and_queued_jobs():
    w = Worker()
    started, release, long = held_job()
    running = w.submit("page", long)
    assert started.wait(10)
    queued = w.submit("another page", lambda check: "not reached either")
    w.cancel_all()
    release.set()
    for fut in (running, queued):
        with pytest.raises(Superseded):
            fut.result(10)
    w.stop()


def test_a_job_that_yields_gives_way_to_a_page_and_goes_on_after_it():
    """A script's job checks between its steps; a page's job submitted meanwhile runs first,
    then the script's job is called again and goes on from the steps it kept."""
    w = Worker()
    order: list[str] = []
    done_steps: list[int] = []
    calls = []
    page_in = threading.Event()

    def script(check: Check) -> int:
        calls.append(len(done_steps))
        while len(done_steps) < 6:
            if len(done_steps) == 3 and not page_in.is_set():
                w.submit("page", lambda check: order.append("page"))  # while it runs
                page_in.set()
            check()
            done_steps.append(1)
        order.append("script")
        return len(done_steps)

    result = w.submit("api", script, yields=True)
    assert result.result(10) == 6
    assert order == ["page", "script"] and calls == [0, 3]  # went on from its 3 steps
    assert w.waiting() == 0 and w._latest == {} and w._queued == {}
    w.stop()


def test_a_job_that_yielded_and_was_cancelled_meanwhile_ends_superseded():
    w = Worker()
    gate, calls = threading.Event(), []

    def page(check: Check) -> str:
        w.cancel("api")  # the script's client went away while the page's job ran
        return "page"

    def script(check: Check) -> str:
        calls.append(1)
        if len(calls) == 1:
            w.submit("page", page)
        gate.wait(0.1)
        check()
        return "not reached"

    result = w.submit("api", script, yields=True)
    with pytest.raises(Superseded):
        result.result(10)
    assert calls == [1]  # not called again once cancelled
    assert w.waiting() == 0 and w._latest == {} and w._queued == {}
    w.stop()


def test_pages_take_turns_a_long_job_gives_way_after_its_slice():
    """Two pages' long jobs and a third page's short one: the short one runs within about a
    slice of the first, not after the long ones end; the long ones give way in turn and each
    goes on (called again) until it ends."""
    import time

    w = Worker(slice_s=0.2)
    order: list[str] = []
    calls = {"a": 0, "b": 0}

    def long(name: str) -> Callable[[Check], str]:
        steps = []

        def job(check: Check) -> str:
            calls[name] += 1
            while len(steps) < 40:  # 40 steps of 20 ms: 0.8 s alone
                check()
                time.sleep(0.02)
                steps.append(1)
            order.append(name)
            return name
        return job

    t0 = time.monotonic()
    a = w.submit("page a", long("a"))
    b = w.submit("page b", long("b"))
    time.sleep(0.05)
    c = w.submit("page c", lambda check: (order.append("c"), time.monotonic() - t0)[1])
    assert c.result(10) < 0.6  # a's slice, then b's at most
    assert a.result(10) == "a" and b.result(10) == "b"
    assert order[0] == "c" and calls["a"] >= 2 and calls["b"] >= 2
    assert w.waiting() == 0 and w._latest == {} and w._queued == {}
    w.stop()


def test_a_job_alone_does_not_give_way_and_slices_double():
    """Without another owner waiting a job runs on past its slice; against another one's, its
    slice doubles at each turn it gives, so that it ends."""
    import time

    w = Worker(slice_s=0.05)
    calls = []

    def job(check: Check) -> int:
        calls.append(time.monotonic())
        t = time.monotonic()
        while time.monotonic() - t < 0.3:
            check()
            time.sleep(0.005)
        return len(calls)

    assert w.submit("alone", job).result(10) == 1
    calls.clear()
    other_done = []

    def other(check: Check) -> None:  # a page that keeps sending new inputs
        for _ in range(200):
            check()
            time.sleep(0.002)
        other_done.append(1)

    running = w.submit("page", job)
    for _ in range(60):  # 3 s of a page that always waits
        w.submit("busy page", other)
        time.sleep(0.05)
        if running.done():
            break
    assert running.done(), "it never ended while another page waited"
    assert running.result() >= 2  # it gave way, then ended on a doubled slice
    w.stop()
