"""The browser link's safety rules (no rclpy, no server): what a message from a page may do.

Every rule here exists because an operator interface got it wrong (their issue trackers:
hello-robot/stretch_web_teleop #3, #38, #109; personalrobotics/feeding_web_interface #125, #126, #175;
rosbridge keeps a closed client's publisher for 10 s, `unregister_timeout`):
- input is stamped by the station when it arrives (browser clocks are not synced), rate-limited, and
  only the latest is kept: nothing is queued or replayed after a lag or a reconnect;
- an input older than ``stale_after`` (by the browser's sequence and clock, referred to the server's
  clock) is dropped, and the held value expires ``stale_after`` after it arrived, so a cut link gives
  zero without waiting for a close;
- a closed socket, a missed heartbeat or a hidden page gives zero at once; so does a hold (the
  caregiver's stop on a stale live view: ``Link.hold``), which refuses motion while it lasts;
- every stop the operator did not choose disarms the driver: motion needs a neutral input after it
  (the arming rule, whose one home is ``vla_common.arming``);
- one client drives; the others watch and may only press the e-stop; a new driver starts at neutral,
  so a reload never re-sends motion; a watcher takes control only deliberately (``claim`` with
  ``confirm: true``) and only while the driver's input is at rest (see ``Link._claim``);
- malformed, oversized, unknown or forbidden messages are dropped and counted; none moves the arm;
- answers to the questionnaire come only from the driving page, for the questionnaire that waits, with
  a whole number on its scale for every statement asked and no other (:mod:`.questionnaire`); an
  answered questionnaire takes no second answer.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from vla_common.arming import Arming

from vla_operator.questionnaire import Questionnaire, answers_problem, ordered
from vla_operator.schema import MODELS, check, parse

# What a page may ask for; everything but "input" and "heartbeat" becomes a request to a node.
REQUESTS = {
    "estop": "latch the bridge's e-stop (any client)",
    "release_estop": "release it (the driver, with confirm: true)",
    "select": "latch an object: by class, index or pixel",
    "gripper": "toggle the hand",
    "ee_next": "the end-effector baseline's next axis (the controller's mode button)",
    "redetect": "drop the latched object and latch the next detection",
    "teaching": "teaching mode on or off",
    "episode": "start (with a task), stop or discard a recording",
    "settings": "caregiver settings (speed scale, deadband, action mode, key map)",
    "answers": "the answers to the questionnaire that waits (the driver)",
}
KINDS = {"input", "heartbeat", "hidden", "claim", *REQUESTS}
assert KINDS == set(MODELS), "every kind of message has its schema (schema.py)"
WATCHER_MAY = {"heartbeat", "estop", "claim", "hidden"}


@dataclass(frozen=True)
class LinkParams:
    stale_after: float = 0.15        # s: an input older than this is dropped; a held one expires
    min_interval: float = 0.01       # s: inputs closer than this are coalesced (the latest wins)
    heartbeat_timeout: float = 0.5   # s without any message from the driver: zero
    max_message_bytes: int = 2048


@dataclass
class Client:
    cid: int
    driver: bool = False
    last_seen: float = -math.inf
    last_seq: int = -1
    offset: float = math.inf         # min over inputs of (server time - browser time): the link's base delay
    may_drive: bool = True           # False: a display page (?watch=1) that never drives
    # a driver's input moves only after a neutral one: at first, and after any stop it did not choose
    arming: Arming = field(default_factory=lambda: Arming(armed=False, reason="a new or reloaded page"))

    @property
    def armed(self) -> bool:
        return self.arming.armed


@dataclass
class Counters:
    received: int = 0
    accepted: int = 0
    malformed: int = 0
    oversized: int = 0
    unknown: int = 0
    forbidden: int = 0
    stale: int = 0
    coalesced: int = 0
    not_armed: int = 0
    held: int = 0                    # motion refused while the link is held (a stale live view)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Verdict:
    """What to do with one message: ``publish`` the new axis now, hand ``request`` to the node, or
    reply ``error`` to the client (the connection always survives)."""

    publish: bool = False
    request: dict | None = None
    error: str = ""
    from_neutral: bool = False       # a press after the driver's accepted neutral: publish that neutral
                                     # first (see Link._input)


@dataclass
class Link:
    params: LinkParams = field(default_factory=LinkParams)
    clients: dict[int, Client] = field(default_factory=dict)
    counters: Counters = field(default_factory=Counters)
    axis: float = 0.0                # the latest accepted input, in [-1, 1]
    axis_t: float = -math.inf        # when it arrived (server clock)
    questionnaire: Questionnaire | None = None   # the one that waits for the driver's answers
    held: str = ""                   # why motion is held (stopped and refused), "" when it is not
    last_publish: float = -math.inf
    _next_id: int = 0

    # ------------------------------------------------------------------ clients
    def connect(self, now: float, may_drive: bool = True) -> Client:
        """A new client: the driver when nobody drives (and it may), else a watcher."""
        self._next_id += 1
        c = Client(self._next_id, driver=may_drive and self.driver() is None, last_seen=now,
                   may_drive=may_drive)
        self.clients[c.cid] = c
        return c

    def disconnect(self, cid: int) -> bool:
        """Forget a client; True when it drove (the caller publishes zero at once)."""
        c = self.clients.pop(cid, None)
        if c is not None and c.driver:
            self.stop()
            return True
        return False

    def driver(self) -> Client | None:
        return next((c for c in self.clients.values() if c.driver), None)

    def stop(self) -> None:
        self.axis, self.axis_t = 0.0, -math.inf

    def value(self, now: float) -> float:
        """The axis to publish now: the latest input while it is fresh, else zero."""
        if now - self.axis_t > self.params.stale_after:
            return 0.0
        return self.axis

    def tick(self, now: float) -> bool:
        """The heartbeat rule: True when the driver just went silent while its input moved the arm
        (publish zero). It keeps the role (a busy browser is not a thief) but must send a neutral input
        again before moving. A silence at rest (its latest input neutral) changes nothing: nothing is
        held that could resume, and a later press is new input, checked as any other (a starved page
        used to be disarmed at rest, and its next press did nothing until released)."""
        d = self.driver()
        if (d is not None and d.armed and self.axis != 0.0
                and now - d.last_seen > self.params.heartbeat_timeout):
            d.arming.disarm("the page went silent while moving")
            self.stop()
            return True
        return False

    def hold(self, why: str) -> bool:
        """Hold all motion (the caregiver's stop on a stale view): zero now, and motion refused while
        held. A stop as any other: a driver whose input moved the arm, or who presses during the hold,
        must send a neutral input before moving after it; one at rest holds nothing and is not
        disarmed (as a silence at rest, see ``tick``). True when the hold starts now (publish zero)."""
        if self.held:
            return False
        self.held = why
        d = self.driver()
        if d is not None and self.axis != 0.0:
            d.arming.disarm(why)
        self.stop()
        return True

    def release_hold(self) -> None:
        """Motion may follow again, after the driver's neutral (it was disarmed by the hold)."""
        self.held = ""

    # ------------------------------------------------------------------ messages
    def on_message(self, cid: int, raw: str | bytes, now: float) -> Verdict:
        c = self.clients.get(cid)
        self.counters.received += 1
        if c is None:
            return self._drop("unknown", "not connected")
        if len(raw) > self.params.max_message_bytes:
            return self._drop("oversized", f"message over {self.params.max_message_bytes} bytes")
        msg = parse(raw)
        if isinstance(msg, str):
            return self._drop("malformed", msg)
        kind = msg["type"]
        if kind not in KINDS:
            return self._drop("unknown", "unknown message type")   # never quoted: a peer's text
        c.last_seen = now
        if not c.driver and kind not in WATCHER_MAY:
            return self._drop("forbidden", "another station drives; a watcher may only press the e-stop")
        msg = check(msg)       # the schema: only the kind's fields, each checked; or why not (its name)
        if isinstance(msg, str):
            return self._drop("malformed", msg)
        if kind == "heartbeat":
            self.counters.accepted += 1
            return Verdict()
        if kind == "claim":
            return self._claim(c, msg, now)
        if kind == "hidden":
            self.counters.accepted += 1
            if c.driver:
                c.arming.disarm("the page was hidden")
                self.stop()
                return Verdict(publish=True)
            return Verdict()
        if kind == "input":
            return self._input(c, msg, now)
        if kind == "answers":
            return self._answers(msg)
        self.counters.accepted += 1
        return Verdict(request=msg)

    def _answers(self, msg: dict) -> Verdict:
        """The driver's answers: checked against the questionnaire that waits (the page is untrusted);
        once accepted it waits no more, so a second send (a replay, a double click) is stale."""
        q = self.questionnaire
        problem = answers_problem(q, msg)
        if problem:
            return self._drop(*problem)
        self.questionnaire = None
        self.counters.accepted += 1
        return Verdict(request={"type": "answers", "id": q.qid, "answers": ordered(q, msg["answers"])})

    def _input(self, c: Client, msg: dict, now: float) -> Verdict:
        seq, t, axis = msg["seq"], msg["t"], msg["axis"]
        if seq <= c.last_seq:
            return self._drop("stale", f"input {seq} is not newer than {c.last_seq}")
        c.last_seq = seq
        # The browser's clock is not ours: the smallest (arrival - sent) seen is the link's base delay,
        # and an input that took longer than that by more than stale_after is old news.
        delay = now - t / 1000.0
        c.offset = min(c.offset, delay)
        if delay - c.offset > self.params.stale_after:
            return self._drop("stale", f"input {seq} arrived {delay - c.offset:.3f} s late")
        if axis != 0.0 and self.held:
            c.arming.disarm(self.held)        # after the hold: let go first
            return self._drop("held", f"stopped: {self.held}")
        why = c.arming.reason
        if not c.arming.offer(neutral=axis == 0.0):
            return self._drop("not_armed", f"motion needs a neutral input first ({why})")
        self.counters.accepted += 1
        # A press after the operator's own neutral: its first command is never held back, and that
        # neutral is published again just before it. A consumer that missed the neutral stream for a
        # moment (the controller's joy_timeout on a starved machine) would otherwise take the press
        # as a stick held through a stop and wait for neutral: a press that did nothing. The neutral
        # is the operator's (accepted, not an expiry or a stop: those leave or set armed differently).
        from_neutral = self.axis == 0.0 and axis != 0.0
        self.axis, self.axis_t = float(axis), now
        if now - self.last_publish < self.params.min_interval and axis != 0.0 and not from_neutral:
            self.counters.coalesced += 1   # kept as the latest; the node's timer publishes it
            return Verdict()
        return Verdict(publish=True, from_neutral=from_neutral)

    def _claim(self, c: Client, msg: dict, now: float) -> Verdict:
        """A watcher asks to drive. Nobody drives (the driver's page closed or went away): it drives.
        A driver is there: only with ``confirm: true`` (a dialog on the page, never a stray key) and only
        while the driver's input is at rest, never while it moves the arm. The arm then gets a zero at
        once (``publish``: the link's value is zero), the old driver watches, and the new one must send
        a neutral input before it moves (as a new page): a key held through the change moves nothing."""
        if c.driver:
            self.counters.accepted += 1
            return Verdict()
        if not c.may_drive:
            return self._drop("forbidden", "this page only watches (opened with watch=1)")
        d = self.driver()
        if d is not None:
            if msg.get("confirm") is not True:
                return self._drop("forbidden", "another station drives: taking control needs confirm: true")
            if self.value(now) != 0.0:
                return self._drop("forbidden", "the driving station is moving the arm: "
                                               "take control when it is at rest")
            d.driver = False
            d.arming.disarm("another station took control")
        c.driver = True
        c.arming = Arming(armed=False, reason="you took control: start from neutral")
        self.stop()
        self.counters.accepted += 1
        return Verdict(publish=True, request={"type": "claim", "taken_from": d.cid if d else None})

    def published(self, now: float) -> None:
        self.last_publish = now

    def _drop(self, counter: str, why: str) -> Verdict:
        setattr(self.counters, counter, getattr(self.counters, counter) + 1)
        return Verdict(error=why)
