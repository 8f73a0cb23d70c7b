"""Work done ahead of the render thread, in one helper thread: loading the next body from
disk (~0.2 s each, which the render thread used to wait for at every body change) and
making (or decoding and resizing) the coming views' backgrounds (a procedural room is
~50 ms of numpy and OpenCV, which release the GIL)."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor


class Prefetcher:
    """Results by key, each computed in the helper thread (made on first use):
    ``start(key, fn, *args)`` begins ``fn(*args)`` unless ``key`` is under way already;
    ``get(key, fn, *args)`` returns its result and forgets it, computing ``fn(*args)``
    on the calling thread when it was never started."""

    def __init__(self):
        self._pool = None
        self._futures = {}

    def start(self, key, fn, *args):
        if key in self._futures:
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="glsynth-prefetch")
        self._futures[key] = self._pool.submit(fn, *args)

    def get(self, key, fn, *args):
        future = self._futures.pop(key, None)
        return fn(*args) if future is None else future.result()

    def close(self):
        """Stop: work not begun is dropped, work under way is waited for."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        self._futures = {}
