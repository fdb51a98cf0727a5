"""Threads of the batched lengths inversion (``capsmech.inversion.tube_batch``): processes run
side by side (test workers, a workflow's jobs, a scheduler's tasks) are told their share of
the cores by ``OMP_NUM_THREADS``, and a batch then starts no more threads than that."""
from __future__ import annotations

import os

import numpy as np
import pytest
from thread_pools import spy_on_pools

from capsmech.inversion import tube_batch
from capsmech.inversion.fitting import tube_inverter
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database


def cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@pytest.mark.parametrize(("bound", "expected"), [("1", 1), ("", None), ("0", None), ("two", None), (" 1 ", 1)])
def test_the_thread_bound_is_read_where_it_is_a_positive_integer(monkeypatch, bound, expected):
    monkeypatch.setenv(tube_batch.THREADS_ENV, bound)
    assert tube_batch.default_workers() == (expected if expected is not None else cores())


def test_a_process_bound_to_one_thread_starts_no_pool(monkeypatch):
    """A batch large enough for several threads (chunks and the thread threshold made small)
    is fitted in this thread when the bound is 1, with the same result as on two threads."""
    started = spy_on_pools(monkeypatch)
    monkeypatch.setattr(tube_batch, "CHUNK", 20)
    monkeypatch.setattr(tube_batch, "MIN_THREAD_CAPSULES", 20)
    inverter = tube_inverter(load_database(database_path("tube-paper")), "NH")
    rows = np.random.default_rng(3).choice(len(inverter.table.L_z), 80, replace=False)
    l_z, l_p = inverter.table.L_z[rows] * 1.002, inverter.table.L_p[rows] * 0.998
    monkeypatch.setenv(tube_batch.THREADS_ENV, "1")
    bound = tube_batch.fit_batch(inverter, l_z, l_p)
    assert started == []
    two = tube_batch.fit_batch(inverter, l_z, l_p, workers=2)
    assert started == [2]
    assert bound.flag == two.flag and np.array_equal(bound.Ca_s, two.Ca_s, equal_nan=True)
    assert bound.ok.sum() > 60
