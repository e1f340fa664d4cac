"""The kernels' threading helpers (``softshadows._jit``): work shared with a launch's slot threads."""

from __future__ import annotations

import threading
import time

import pytest

from softshadows._jit import SharedWork

N_ITEMS = 40


def _claiming_work(started: threading.Event, ended: list):
    """A kernel-shaped Python function ``fn(slot, done, who, nslot)`` whose items are claimed from a
    shared counter, as the package's slot kernels claim theirs (``next_item``): each item is
    counted in ``done`` and its slot written to ``who``; each slot's end time goes to ``ended``.
    Slot 1 claims one item, then lets slot 0 (which waits for that) start, so that both take items
    whatever the threads' timing."""
    lock = threading.Lock()
    nxt = [0]

    def claim():
        with lock:
            i = nxt[0]
            nxt[0] += 1
            return i

    def fn(slot, done, who, nslot):
        if slot == 0 and not started.wait(timeout=10.0):
            raise AssertionError("the helper never started")
        first = True
        while (i := claim()) < len(done):
            done[i] += 1
            who[i] = slot
            if slot == 1 and first:
                started.set()
                first = False
            time.sleep(0.0005)  # both slots take some of the items
        ended.append((slot, time.perf_counter()))

    return fn


def test_shared_work_runs_every_item_once_with_a_helper():
    """A slot thread that comes to ``help`` while the calling thread runs the offered work takes
    items from the same counter; ``run`` returns only once the helper is done: every item computed
    exactly once, some by each thread, none still running when ``run`` returns."""
    share = SharedWork()
    started = threading.Event()
    ended = []
    fn = _claiming_work(started, ended)
    done = [0] * N_ITEMS
    who = [-1] * N_ITEMS

    def helper():
        while not share._task:  # (the offer is published at the start of run)
            time.sleep(0.0001)
        share.help(1)

    t = threading.Thread(target=helper)
    t.start()
    share.run(fn, 2, done, who)
    returned = time.perf_counter()
    t.join(timeout=10.0)
    assert done == [1] * N_ITEMS
    assert 0 in who and 1 in who
    assert sorted(s for s, _ in ended) == [0, 1]
    assert all(end <= returned for _, end in ended)  # run waited for the helper's last item


def test_shared_work_without_a_helper_or_after_it_closed():
    """With no slot thread helping, the calling thread computes every item; a ``help`` after
    ``close`` runs nothing and returns (a launch that ends early or late changes only the time,
    never the result)."""
    share = SharedWork()
    started = threading.Event()
    started.set()  # slot 0 does not wait for a helper
    fn = _claiming_work(started, [])
    done = [0] * N_ITEMS
    who = [-1] * N_ITEMS
    share.run(fn, 2, done, who)
    assert done == [1] * N_ITEMS and set(who) == {0}
    share.close()
    calls = []
    share._task = (lambda *a: calls.append(a), (), 2)  # even a task still set: closed
    share._offers += 1
    share.help(1)
    assert calls == []


def test_shared_work_helper_waits_for_every_offer_until_closed():
    """A slot thread that comes to ``help`` before any offer waits for it, serves each offer made
    while it waits (items claimed from each offer's own counter), and leaves at ``close``: every
    item of every offer computed exactly once."""
    share = SharedWork()
    arrived = threading.Event()
    left = threading.Event()

    def helper():
        arrived.set()
        share.help(1)
        left.set()

    t = threading.Thread(target=helper)
    t.start()
    assert arrived.wait(timeout=10.0)
    time.sleep(0.01)  # (the helper waits in help, no offer open yet)
    assert not left.is_set()
    for _ in range(2):  # two offers, one after the other: the helper serves both
        started = threading.Event()
        fn = _claiming_work(started, [])
        done = [0] * N_ITEMS
        who = [-1] * N_ITEMS
        share.run(fn, 2, done, who)
        assert done == [1] * N_ITEMS
        assert 0 in who and 1 in who
        assert not left.is_set()  # still waiting for the next offer
    share.close()
    t.join(timeout=10.0)
    assert left.is_set() and not t.is_alive()


def test_slot_launch_on_finish_releases_a_waiting_helper():
    """``start_slots(..., on_finish=share.close)``: a slot thread that waits in ``help`` when the
    calling thread joins the launch is let go first (no deadlock), and ``finish`` returns."""
    from softshadows._jit import start_slots

    share = SharedWork()
    ran = []

    def fn(slot):
        ran.append(slot)
        if slot:
            share.help(slot)

    launch = start_slots(fn, 2, on_finish=share.close)
    time.sleep(0.01)
    out = []
    t = threading.Thread(target=lambda: out.append(launch.finish()))
    t.start()
    t.join(timeout=10.0)
    assert not t.is_alive(), "finish() deadlocked on a helper waiting for an offer"
    assert sorted(ran) == [0, 1]


def test_shared_work_raises_the_calling_threads_error_after_the_helpers():
    """An error in the calling thread's part reaches the caller, after the helpers have finished."""
    share = SharedWork()
    helper_done = threading.Event()

    def fn(slot, nslot):
        if slot == 1:
            time.sleep(0.02)
            helper_done.set()
            return
        while share._helpers == 0:  # let the helper join first
            time.sleep(0.0001)
        raise ValueError("slot 0")

    def helper():
        while not share._task:
            time.sleep(0.0001)
        share.help(1)

    t = threading.Thread(target=helper)
    t.start()
    with pytest.raises(ValueError, match="slot 0"):
        share.run(fn, 2)
    assert helper_done.is_set()
    t.join(timeout=10.0)


def test_row_stride_is_the_shortest_odd_number_of_lines_that_holds_the_row():
    """``row_stride(n)`` (a float64 scratch row's length): at least n, a whole number of 64-byte
    lines (8 float64), that number odd, and the shortest such length (so that a column's rows fall
    in different cache sets at the least memory)."""
    from softshadows._jit import py_callable, row_stride

    rs = py_callable(row_stride)
    for n in [1, 7, 8, 9, 15, 16, 17, 255, 256, 257, 512, 1000, 1024, 13088]:
        w = rs(n)
        assert w >= n and w % 8 == 0 and (w // 8) % 2 == 1, (n, w)
        shorter = [v for v in range(n, w) if v % 8 == 0 and (v // 8) % 2 == 1]
        assert not shorter, (n, w, shorter)
    assert rs(256) == 264 and rs(512) == 520 and rs(8) == 8
