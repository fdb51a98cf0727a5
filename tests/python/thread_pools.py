"""A spy on the thread pools ``capsmech.inversion.tube_batch`` starts (the batch-inversion tests)."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

from capsmech.inversion import tube_batch


def spy_on_pools(monkeypatch) -> list[int]:
    """The thread counts of the pools ``tube_batch`` starts, appended as it starts them."""
    started: list[int] = []

    class Pool(ThreadPoolExecutor):
        def __init__(self, max_workers: int) -> None:
            started.append(max_workers)
            super().__init__(max_workers=max_workers)

    monkeypatch.setattr(tube_batch, "ThreadPoolExecutor", Pool)
    return started
