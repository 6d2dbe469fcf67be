"""Is the live view live? (no rclpy): how long since the view last got a new frame, and whether that
makes it stale. The station sends both to the pages in its state (``view_stale``, ``view_age_s``), so
a page never shows a frozen picture as if it were live (issue 32: one bad image froze the view for
good while the page said "Connected to the robot").

A frame counts when it reached the pages (encoded and handed to the server) or, with no page open, when
a showable image arrived (nothing to show it to, but the camera lives): a page that opens then does not
see "stale" for the instant before its first frame.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

STALE_AFTER_S = 1.0     # no new frame for this long: the view is stale
CHECK_PERIOD_S = 0.25   # how often the node looks: a stopped camera shows as stale within 1.25 s
RESEND_STALE_S = 1.0    # while stale, the age is sent again this often (the page can say how old)


class ViewWatch:
    def __init__(self, stale_after: float = STALE_AFTER_S, clock: Callable[[], float] = time.monotonic):
        self.stale_after, self.clock = stale_after, clock
        self._last = -math.inf            # when the view last got a new frame
        self._lock = threading.Lock()     # frames come from the encoder's thread, checks from the node's
        self._sent: tuple[bool, float] | None = None   # (stale, when) last told to the pages

    def seen(self) -> None:
        """A new frame reached the view now."""
        with self._lock:
            self._last = self.clock()

    def fields(self) -> dict:
        """``view_stale`` and ``view_age_s`` (seconds since the last new frame, None before the first)
        as of now, for the state sent to the pages."""
        with self._lock:
            age = self.clock() - self._last
        return {"view_stale": not age <= self.stale_after,
                "view_age_s": round(age, 2) if math.isfinite(age) else None}

    def changed(self) -> dict | None:
        """The fields when the pages must be told (the view went stale or came back, or it has stayed
        stale for another ``RESEND_STALE_S``), else None. Call it every ``CHECK_PERIOD_S``."""
        f, now = self.fields(), self.clock()
        last = self._sent
        if last is not None and last[0] == f["view_stale"] and not (
                f["view_stale"] and now - last[1] >= RESEND_STALE_S):
            return None
        self._sent = (f["view_stale"], now)
        return f
