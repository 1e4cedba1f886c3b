"""Random streams derived from a seed: one per purpose and ids.

>>> rng(7, "terrain").uniform()          # doctest: +SKIP
>>> rng(7, "unique-tree", 0, 3)          # entry 0's fourth drawn tree   # doctest: +SKIP

Every random number the package draws comes from :func:`rng` (numpy) or :func:`key` (the 32-bit key
of a counter-based Dr.Jit stream, scan/sampling.py). Both are a function of ``(seed, purpose, *ids)``
alone: numpy's :class:`~numpy.random.SeedSequence` with the seed as entropy and, as spawn key, a
SHA-256 digest of the purpose followed by the ids. The digest (not Python's ``hash``, which is salted
per process) makes a stream the same in every process and on every machine; distinct purposes or ids
give independent streams, so drawing more for one purpose (one more tree) leaves the others alone.
This module imports no pipeline stage.
"""

from __future__ import annotations

import hashlib

import numpy as np

__all__ = ["rng", "key", "sequence"]


def sequence(seed: int | None, purpose: str, *ids: int) -> np.random.SeedSequence:
    """The :class:`~numpy.random.SeedSequence` of ``(seed, purpose, *ids)``; ``seed`` None draws fresh
    entropy from the operating system (a different stream on every call).

    :param seed: any integer >= 0 (a scene's seed, a model's seed).
    :param purpose: what the stream is for, e.g. ``"terrain"``; each purpose names one stream family.
    :param ids: integers >= 0 that tell the members of a family apart (a tree's index, a plot's number).
    """
    if seed is not None and int(seed) < 0 or any(int(i) < 0 for i in ids):
        raise ValueError(f"seed and ids must be >= 0, got seed {seed}, ids {ids}")
    digest = hashlib.sha256(purpose.encode("utf-8")).digest()
    words = tuple(int.from_bytes(digest[k:k + 4], "little") for k in range(0, 16, 4))
    return np.random.SeedSequence(None if seed is None else int(seed), spawn_key=(*words, *(int(i) for i in ids)))


def rng(seed: int | None, purpose: str, *ids: int) -> np.random.Generator:
    """A numpy Generator (PCG64) of the stream ``(seed, purpose, *ids)``; see :func:`sequence`."""
    return np.random.default_rng(sequence(seed, purpose, *ids))


def key(seed: int, purpose: str, *ids: int, bits: int = 32) -> int:
    """An integer in ``[0, 2**bits)`` of the stream ``(seed, purpose, *ids)``: the key of a Dr.Jit
    counter-based stream (32 bits), or the seed of a model (31 bits, as ``Archetype.seed``).

    :param bits: 1 to 64.
    """
    if not 1 <= bits <= 64:
        raise ValueError(f"bits must be 1 to 64, got {bits}")
    word = int(sequence(seed, purpose, *ids).generate_state(1, np.uint64)[0])
    return word >> (64 - bits)
