"""Random streams that do not depend on how the work is cut up.

A long drive is simulated in pieces (stretches of scene, chunks of scan time), and the same seed
must give the same drive whatever the pieces. So no stream is shared across pieces: each piece
draws from its own child of a seed sequence, named by a number of its own (an object id, a
chunk number) rather than by the order in which pieces happen to be made.
"""

from __future__ import annotations

import numpy as np


def seed_sequence(
    rng: np.random.Generator | np.random.SeedSequence | int | None,
) -> np.random.SeedSequence:
    """The seed sequence of ``rng``: itself, seeded from an int (None: fresh entropy), or drawn
    from a generator (which advances it)."""
    if isinstance(rng, np.random.SeedSequence):
        return rng
    if isinstance(rng, np.random.Generator):
        return np.random.SeedSequence(rng.integers(0, 2**63, size=4).tolist())
    return np.random.SeedSequence(rng)


def child_rng(sequence: np.random.SeedSequence, *key: int) -> np.random.Generator:
    """A generator on the child of ``sequence`` named ``key``: ``child_rng(s, i)`` draws as
    ``default_rng(s.spawn(i + 1)[i])`` would, without spawning (or counting) the others."""
    child = np.random.SeedSequence(
        sequence.entropy,
        spawn_key=(*sequence.spawn_key, *(int(k) for k in key)),
        pool_size=sequence.pool_size,
    )
    return np.random.default_rng(child)
