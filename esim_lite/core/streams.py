"""Random streams derived from a sequence's generator without drawing from it."""

from __future__ import annotations

import numpy as np


def derived_rng(rng: np.random.Generator, key: int, what: str) -> np.random.Generator:
    """A generator of its own for one sensor effect, derived from ``rng`` (a sequence's
    noise stream) by the spawn ``key`` without drawing from ``rng`` or changing it: the
    same ``rng`` gives the same draws, and every draw of ``rng`` stays what it was without
    that effect.

    Raises:
        ValueError: ``rng`` was not seeded through a ``SeedSequence`` (``what`` names the
            effect that needs it).
    """
    seq = rng.bit_generator.seed_seq
    if not isinstance(seq, np.random.SeedSequence):
        raise ValueError(f"{what} needs a generator seeded through a SeedSequence "
                         "(np.random.default_rng(seed))")
    return np.random.default_rng(np.random.SeedSequence(
        seq.entropy, spawn_key=(*seq.spawn_key, key), pool_size=seq.pool_size))
