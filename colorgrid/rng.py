"""Counter-based random numbers, vectorised over a batch of environments.

Every random draw of an environment is a pure function of that environment's
episode seed and a small counter (step, stream, attempt, index).  This is what
lets a batch of N environments run with no Python loop over environments while
env ``i`` still reproduces, bit for bit, a single environment given the same
episode seed: no generator state is shared between environments.

The mixing function is SplitMix64's finaliser (Steele et al., 2014), which
passes BigCrush when used on a counter.
"""

from __future__ import annotations

import numpy as np

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_TO_UNIT = 1.0 / float(1 << 53)

# Streams: one per kind of draw, so draws never collide.
STREAM_LAYOUT = 1
STREAM_SWITCH = 2
STREAM_SWITCH_COLOR = 3
STREAM_RESPAWN = 4
STREAM_NEXT_SEED = 5
STREAM_GOAL = 6

MAX_SEED = (1 << 63) - 1


def mix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser applied elementwise to a uint64 array (ndim >= 1).

    Array arithmetic wraps modulo 2**64 silently, as the finaliser needs.
    """
    x = x ^ (x >> _S30)
    x *= _M1
    x ^= x >> _S27
    x *= _M2
    x ^= x >> _S31
    return x


_MASK = (1 << 64) - 1
_K_STEP, _K_ATTEMPT, _K_INDEX, _K_STREAM = 0x100000001B3, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0x9E3779B97F4A7C15


def _term(value, factor: int):
    """``value * factor`` modulo 2**64: a Python int for scalars, a uint64 array otherwise."""
    if isinstance(value, (int, np.integer)):
        return (int(value) * factor) & _MASK
    return np.asarray(value, dtype=np.uint64) * np.uint64(factor)


def hash64(seed: np.ndarray, step, stream: int, attempt=0, index=0) -> np.ndarray:
    """A uint64 draw for each seed; all arguments broadcast against each other.

    seed: uint64 episode seeds, e.g. ``[B]``; step, attempt, index: integer
    arrays or scalars broadcastable to it; stream: one of the ``STREAM_*`` ids.
    """
    counter = np.atleast_1d(np.asarray(seed, dtype=np.uint64) * np.uint64(0))  # the broadcast shape
    scalar = (stream * _K_STREAM) & _MASK
    for value, factor in ((step, _K_STEP), (attempt, _K_ATTEMPT), (index, _K_INDEX)):
        term = _term(value, factor)
        if isinstance(term, int):
            scalar = (scalar + term) & _MASK
        else:
            counter = counter + term
    counter = counter + np.uint64(scalar)
    return mix64(mix64(np.asarray(seed, dtype=np.uint64) ^ counter) + counter)


def uniform(seed: np.ndarray, step, stream: int, attempt=0, index=0) -> np.ndarray:
    """Float64 draws in [0, 1), 53 random bits each."""
    bits = hash64(seed, step, stream, attempt, index) >> _S11
    return bits.astype(np.float64) * _TO_UNIT


def below(seed: np.ndarray, n, step, stream: int, attempt=0, index=0) -> np.ndarray:
    """Integer draws in [0, n) (``n`` broadcastable); bias below 2**-40 for n < 2**24."""
    return (hash64(seed, step, stream, attempt, index) % np.asarray(n, dtype=np.uint64)).astype(np.int64)


def next_episode_seed(seed: np.ndarray) -> np.ndarray:
    """The seed of the episode that follows an episode with ``seed`` (autoreset)."""
    return hash64(seed, 0, STREAM_NEXT_SEED) >> np.uint64(1)


def fresh_seed() -> int:
    """A seed drawn from operating-system entropy, in [0, 2**63)."""
    return int(np.random.SeedSequence().entropy) & MAX_SEED
