"""What one page may cost the station (asyncio, no server): a bounded outgoing queue, and budgets for
what it sends. Issue 32: a page that sent junk at 50 k messages/s and never read the replies delayed
another page's e-stop by 5-12 s, and the station's memory grew from 136 to 343 MB and stayed there; a
DDS peer's 60 KB status texts at 350 Hz added 215 MB in 10 s while a page read slowly.

- :class:`Outbox`: replies and roles in order, at most ``max_messages`` (the oldest dropped past it),
  at most ``max_refusals`` refusals (the oldest dropped), and only the newest state and the newest frame
  (a newer one replaces the one not yet sent). A page that reads slowly, or never, costs at most that,
  whatever the rate of what is sent to it; one sender per page sends it as the page reads.
- :class:`Budget`: a token bucket. A page's messages beyond their budget are not handled (an e-stop
  always is), and a page whose refusals go past theirs is closed.
"""
from __future__ import annotations

import asyncio
from collections import deque
from dataclasses import dataclass


class Outbox:
    def __init__(self, max_messages: int = 64, max_refusals: int = 8):
        self._messages: deque = deque(maxlen=max_messages)
        self._refusals: deque = deque(maxlen=max_refusals)
        self._latest: dict[str, object] = {}       # "state": text, "frame": (meta, jpeg)
        self._ready = asyncio.Event()
        self._closed = False
        self.dropped = 0                           # messages dropped because the page did not read

    def put(self, text: str) -> None:
        """A reply, a role, a hello: sent in order; the oldest goes when the page has not read them."""
        self._append(self._messages, text)

    def refuse(self, text: str) -> None:
        """A refusal: only the last few are kept for a page that does not read."""
        self._append(self._refusals, text)

    def latest(self, kind: str, payload: object) -> None:
        """The newest state or frame: replaces the one not yet sent."""
        if kind in self._latest:
            self.dropped += 1
        self._latest[kind] = payload
        self._ready.set()

    def close(self) -> None:
        self._closed = True
        self._ready.set()

    def __len__(self) -> int:
        return len(self._messages) + len(self._refusals) + len(self._latest)

    def _append(self, q: deque, text: str) -> None:
        if len(q) == q.maxlen:
            self.dropped += 1
        q.append(text)
        self._ready.set()

    async def next(self) -> tuple[str, object] | None:
        """The next thing to send: ("text", str) or ("frame", (meta, jpeg)); None once closed. Replies
        and roles first, then refusals, then the state, then the frame."""
        while True:
            if self._closed:
                return None
            if self._messages:
                return "text", self._messages.popleft()
            if self._refusals:
                return "text", self._refusals.popleft()
            for kind in ("state", "frame"):
                if kind in self._latest:
                    return ("text" if kind == "state" else kind), self._latest.pop(kind)
            self._ready.clear()
            await self._ready.wait()


@dataclass
class Budget:
    """A token bucket: ``take`` succeeds while fewer than ``burst`` were taken beyond ``rate`` per s."""

    rate: float
    burst: float
    tokens: float = -1.0
    t: float = 0.0

    def take(self, now: float) -> bool:
        if self.tokens < 0.0:
            self.tokens, self.t = self.burst, now
        self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate)
        self.t = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False
