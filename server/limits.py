"""Rate limits for clients: token buckets, a flood rule, and per-address buckets of bounded size."""

from __future__ import annotations

import time
from collections import OrderedDict, deque
from collections.abc import Callable


class TokenBucket:
    """``rate`` events per second sustained, bursts of ``burst``; ``clock`` gives the time in seconds (a test's
    own clock)."""

    def __init__(self, rate: float, burst: float, clock: Callable[[], float] = time.monotonic):
        self.rate, self.burst, self.clock = rate, burst, clock
        self.tokens = burst
        self.refill_at = clock()

    def allow(self) -> bool:
        now = self.clock()
        self.tokens = min(self.burst, self.tokens + (now - self.refill_at) * self.rate)
        self.refill_at = now
        if self.tokens >= 1:
            self.tokens -= 1
            return True
        return False

    def retry_after(self) -> float:
        """Seconds until the next event would be allowed."""
        return max(0.0, (1 - self.tokens) / self.rate)


class FloodRule:
    """More than ``limit`` refused messages within ``window_s`` seconds is a flood.

    With the server's defaults (40 messages/s allowed, limit 5 x 40 in 5 s), a client that
    keeps sending at twice the allowed rate is a flood after about 5 s, and one sending
    hundreds a second within a fraction of a second.
    """

    def __init__(self, limit: int, window_s: float = 5.0, clock: Callable[[], float] = time.monotonic):
        self.limit, self.window_s, self.clock = limit, window_s, clock
        self.refused: deque[float] = deque()

    def refuse(self) -> bool:
        """Count one refused message; True when that makes a flood."""
        now = self.clock()
        self.refused.append(now)
        while self.refused and now - self.refused[0] > self.window_s:
            self.refused.popleft()
        return len(self.refused) > self.limit


class AddressLimits:
    """One ``TokenBucket`` per client address; the least recently seen are forgotten beyond ``max_addresses``."""

    def __init__(self, rate: float, burst: float, max_addresses: int = 10_000):
        self.rate, self.burst, self.max_addresses = rate, burst, max_addresses
        self.buckets: OrderedDict[str, TokenBucket] = OrderedDict()

    def bucket(self, address: str) -> TokenBucket:
        bucket = self.buckets.pop(address, None) or TokenBucket(self.rate, self.burst)
        self.buckets[address] = bucket
        while len(self.buckets) > self.max_addresses:
            self.buckets.popitem(last=False)
        return bucket
