"""Row-parallel numpy: a function of arrays whose rows are independent, computed in
fixed blocks of rows on a few threads (numpy's gathers and arithmetic and OpenCV release
the GIL). Painting a body's texels and a lesion's decal pixels run ~1.5x faster on 2
cores. The blocks do not depend on the number of threads, so neither do the values."""
from __future__ import annotations

import os
import threading

import numpy as np

BLOCK_ROWS = 1 << 18
_THREAD_PREFIX = "glsynth-rows"
_pool = (None, None)   # (process id, executor): a forked child makes its own


def by_rows(fn, *arrays):
    """``fn(*arrays)`` for arrays of equal length whose rows are independent (``fn``
    returns one array with a row per input row): the results of ``fn`` on consecutive
    blocks of ``BLOCK_ROWS`` rows, concatenated."""
    global _pool
    n = len(arrays[0])
    if n <= BLOCK_ROWS or (os.cpu_count() or 1) < 2:
        return fn(*arrays)
    starts = range(0, n, BLOCK_ROWS)

    def block(k):
        return fn(*(a[k:k + BLOCK_ROWS] for a in arrays))

    if threading.current_thread().name.startswith(_THREAD_PREFIX):
        # A call from inside a block runs its blocks inline: waiting on the same pool
        # from all its threads would deadlock. Same blocks, so the same values.
        return np.concatenate([block(k) for k in starts])
    if _pool[0] != os.getpid():
        from concurrent.futures import ThreadPoolExecutor
        _pool = (os.getpid(), ThreadPoolExecutor(min(4, os.cpu_count()), thread_name_prefix=_THREAD_PREFIX))
    return np.concatenate(list(_pool[1].map(block, starts)))
