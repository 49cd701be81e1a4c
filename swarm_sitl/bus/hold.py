"""Lockstep: the supervisor holding the swarm at a tick, for a page's pause and single step.

``LockstepHold`` publishes the hold (``bus.keys.hold``): the last tick a node may finish before it
waits (``bus.clock.wait_while_held``). Pausing is in two steps, since the supervisor does not know
where each node is at the moment (a lockstep run does thousands of ticks a second, and a
follower's status comes every ``run.status_every`` of them):

1. the hold goes to -1: every node finishes the tick it is on and waits, each follower saying
   with a status where it stopped;
2. the hold goes to the furthest tick a follower stopped at (and on, should a later status
   come): the followers behind it run up to it. The swarm is then held at one tick, every
   follower's status saying so for ``SETTLE_S`` (``held_at``); the leader, which runs ahead,
   waits where it is. (A follower that heard the hold late and waits, mid-tick, for an input
   held before it says where it is after ``bus.clock.wait_until``'s idle period, 50 ms: until
   then its status can read the hold's tick from before.)

The page's live feed makes the hold (``view.live``: a page may ask for a pause before the run
has started, and the run then holds after its first tick); the run's supervisor gives it the put
once its session is open and acts on it as the run goes (``running.run``).

A step raises the hold by a tick count: every follower runs that many ticks and says where it
is. Resuming publishes ``codec.HOLD_NONE``. The hold is put again every ``REPUT_EVERY_S`` (a put
keeps no history: a node restarted by a fault plan hears it then).

The page's requests come on the server's threads (``control``), and the supervisor's loop acts on
them (``act``): a lock is held only to hand them over.
"""

import threading
from collections.abc import Callable

from swarm_sitl.bus.codec import HOLD_NONE, Status

REPUT_EVERY_S = 0.5  #: how often a hold is put again [s]
STOP = -1  #: the hold that stops every node after the tick it is on
MAX_STEP_TICKS = 100_000  #: the most ticks one step request may run
#: how long every follower's status must say the hold's tick before the run is held there [s]
SETTLE_S = 0.25


class LockstepHold:
    """The hold of a lockstep run of ticks ``0..last_tick``, put on the bus by ``put(tick)``
    (``bus.session.publish_hold``; given by the run once its session is open)."""

    def __init__(self, last_tick: int, put: Callable[[int], None] | None = None):
        self.put = put
        self.last_tick = last_tick
        self._lock = threading.Lock()
        self._asked: list[tuple[str, int]] = []  #: ("pause" | "resume" | "step", ticks), in order
        self.tick = HOLD_NONE  #: the hold as last put
        self._next_put = 0.0
        #: set by ``act``, read by the page's threads
        self.paused = False
        self.held_at: int | None = None  #: the tick every follower is held at, once they are
        self._level_since: float | None = None  #: since when every follower's status says the hold

    # -- the page's threads ----------------------------------------------------------------------
    def control(self, pause: str | None, step: int) -> tuple[int, str]:
        """A page's request: ``pause`` "toggle", "on" or "off", or ``step`` ticks of a paused run.
        An HTTP status and one line."""
        if pause is not None and pause not in ("toggle", "on", "off"):
            return 400, f"pause must be toggle, on or off, not {pause[:40]!r}"
        if pause is None and step <= 0:
            return 400, "say pause=toggle|on|off or step=<ticks>"
        if step > MAX_STEP_TICKS:
            return 400, f"a step runs at most {MAX_STEP_TICKS} ticks, not {step}"
        with self._lock:
            will_pause = self._will_pause()
            if pause is not None:
                want = {"toggle": not will_pause, "on": True, "off": False}[pause]
                self._asked.append(("pause" if want else "resume", 0))
                return 200, "pausing the run" if want else "resuming the run"
            if not will_pause:
                return 409, "the run is not paused: pause it first, then step"
            self._asked.append(("step", step))
            return 200, f"stepping the run {step} tick{'s' * (step != 1)}"

    def _will_pause(self) -> bool:
        """Whether the run is paused once what is asked has been acted on (under the lock)."""
        paused = self.paused
        for what, _ in self._asked:
            paused = what in ("pause", "step") or (paused and what != "resume")
        return paused

    # -- the supervisor's loop -------------------------------------------------------------------
    def act(self, statuses: dict[int, Status], down: set[int], now: float) -> None:
        """Act on what the page asked, move the hold up to the furthest follower while pausing,
        and put it when it changes or is due again. ``statuses``: each follower's newest;
        ``down``: nodes down now (not waited for); ``now``: ``time.monotonic()``."""
        if self.put is None:
            return
        with self._lock:
            asked, self._asked = self._asked, []
        live = [s.step for i, s in statuses.items() if i not in down]  # where each live follower is
        furthest = max(live, default=STOP)
        hold = self.tick
        for what, ticks in asked:
            if what == "pause" and not self.paused:
                self.paused, hold = True, STOP
            elif what == "resume":
                self.paused, hold = False, HOLD_NONE
            elif what == "step" and self.paused:
                hold = max(hold, furthest) + ticks
        if self.paused:
            hold = max(hold, furthest)  # (a follower that stopped past the hold: the others come)
        hold = min(hold, self.last_tick) if hold != HOLD_NONE else hold
        level = self.paused and bool(live) and all(k == hold for k in live) and hold == self.tick
        self._level_since = (now if self._level_since is None else self._level_since) if level else None
        settled = self._level_since is not None and now - self._level_since >= SETTLE_S
        self.held_at = hold if settled else None
        if hold != self.tick or (self.tick != HOLD_NONE and now >= self._next_put):
            self.tick = hold
            self.put(hold)
            self._next_put = now + REPUT_EVERY_S
