"""Batched ray tests in one pybullet client, in batches pybullet accepts."""
from __future__ import annotations

import numpy as np
import pybullet as pb

MAX_RAYS_PER_BATCH = 16000


def ray_cast(client: int, starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched ray tests ``starts -> ends`` ``(N, 3)`` in a client's frame: the body id ``(N,)`` int64
    first hit by each ray (-1 for none) and the fraction of its length where it hit ``(N,)`` (1.0 for
    none)."""
    n = len(starts)
    uids = np.full(n, -1, dtype=np.int64)
    frac = np.ones(n)
    for lo in range(0, n, MAX_RAYS_PER_BATCH):
        hi = min(n, lo + MAX_RAYS_PER_BATCH)
        res = pb.rayTestBatch(starts[lo:hi].tolist(), ends[lo:hi].tolist(), physicsClientId=client)
        uids[lo:hi] = [r[0] for r in res]
        frac[lo:hi] = [r[2] if r[0] >= 0 else 1.0 for r in res]
    return uids, frac
