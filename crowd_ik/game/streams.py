"""The game's random numbers: one counter-based hash, split into named streams.

Every random choice in the game is `rand(seed, STREAM, index, counter)`: a pure function of the
scene's seed and of what is drawn (which character, which shot), never of the order of the calls,
so the same scene and seed give the same game at any thread count.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry import rng

# the first argument of the hash is seed + stream
LAYOUT, CHARACTER, FIRE, SHARD, SIDE, WANDER, AUTOPILOT = ((1 << 20) * np.arange(1, 8)).tolist()


def rand(seed: int, stream: int, index, counter) -> np.ndarray:
    """float32 in [0, 1) from the counter-based hash: (seed + stream, index, counter) broadcast."""
    return rng.uniform((int(seed) + int(stream)) & 0xFFFFFFFF, index, counter)
