"""Every random choice flows from the root seed and the identity of the task, so a
dataset is the same whatever the executor or the number of workers."""
from __future__ import annotations

import zlib

import numpy as np


def rng_for(seed: int, *keys) -> np.random.Generator:
    """A generator for the task named by ``keys`` (strings or ints) under ``seed``."""
    words = [int(seed)]
    for k in keys:
        words.append(int(k) if isinstance(k, (int, np.integer)) else zlib.crc32(str(k).encode()))
    return np.random.default_rng(np.random.SeedSequence(words))


def torch_seed(seed: int, *keys) -> int:
    return int(rng_for(seed, "torch", *keys).integers(0, 2**31 - 1))
