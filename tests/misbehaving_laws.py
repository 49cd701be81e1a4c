"""Laws that misbehave in follower 2 from t = 0.5 s, each as a user's buggy law would: the
guard (``nodes.law_guard``) and the supervisor must end the run with one line naming it, keep
what was recorded and leave no process (``test_misbehaving_laws*``)."""

import os
import sys
import time
from typing import ClassVar

import numpy as np
from pydantic import BaseModel

from swarm_sitl.laws.contract import AttitudeCommand, LawOutput

FROM_S = 0.5  #: when follower 2's law starts to misbehave
SLOW_S = 0.05  #: ``Slow``'s time per tick
HOARD_BYTES = 16_000_000  #: what ``Hoards`` keeps each tick
CHATTER = "x" * 10_000  #: what ``Chatty`` prints each tick


class Hover:
    message_length = 3
    record_fields: ClassVar = {"n_heard": 1}

    def __init__(self, ctx):
        self.weight = ctx.mass_kg * ctx.gravity_mps2
        self.id = ctx.follower_id
        self.hoard = []

    def bad(self, t):
        return self.id == 2 and t >= FROM_S - 1e-9

    def step(self, t, sample, inbox):
        self.misbehave(t)
        q = np.array([1.0, 0.0, 0.0, 0.0])
        return LawOutput(AttitudeCommand(q, self.weight), np.zeros(3), {"n_heard": len(inbox)})

    def misbehave(self, t):
        pass


class SysExit(Hover):
    def misbehave(self, t):
        if self.bad(t):
            sys.exit(0)


class OsExit(Hover):
    def misbehave(self, t):
        if self.bad(t):
            os._exit(3)


class Loops(Hover):
    def misbehave(self, t):
        while self.bad(t):
            pass


class Slow(Hover):
    def misbehave(self, t):
        if self.id == 2:
            time.sleep(SLOW_S)


class Hoards(Hover):
    def misbehave(self, t):
        if self.bad(t):
            self.hoard.append(np.ones(HOARD_BYTES // 8))


class Chatty(Hover):
    def misbehave(self, t):
        if self.id == 2:
            print(CHATTER)


class SleepParams(BaseModel):
    sleep_s: float = 0.0  #: every tick of follower 2 [s]


class Sleeps(Hover):
    """Follower 2 sleeps ``params.sleep_s`` each tick (a campaign varies it)."""

    Params = SleepParams

    def __init__(self, ctx):
        super().__init__(ctx)
        self.sleep_s = ctx.params.sleep_s

    def misbehave(self, t):
        if self.id == 2 and self.sleep_s:
            time.sleep(self.sleep_s)


class MixedExits(Hover):
    """In one run: follower 2 calls ``sys.exit(0)``, 3 ``os._exit(3)``, 4 loops forever."""

    def misbehave(self, t):
        if t >= FROM_S - 1e-9:
            {2: SysExit, 3: OsExit, 4: Loops}.get(self.id, Hover).misbehave(self._as_2(), t)

    def _as_2(self):
        twin = Hover.__new__(Hover)
        twin.id, twin.hoard = 2, self.hoard
        return twin


class MixedLoads(Hover):
    """In one run: follower 2 hoards memory, 3 is slow, 4 chatters."""

    def misbehave(self, t):
        {2: Hoards, 3: Slow, 4: Chatty}.get(self.id, Hover).misbehave(self._as_2(), t)

    _as_2 = MixedExits._as_2


class HeldWhenDeaf(Hover):
    """Held in compiled code (its guard's signal blocked, then asleep) from the first tick at which
    it hears nobody after 0.2 s: a law a fault plan that cuts its in-edges makes hang for good."""

    def misbehave(self, t):
        pass

    def step(self, t, sample, inbox):
        if t >= 0.2 and not inbox:
            import signal as _signal

            from swarm_sitl.nodes.law_guard import _SIGNAL

            _signal.pthread_sigmask(_signal.SIG_BLOCK, [_SIGNAL])
            time.sleep(60)
        return super().step(t, sample, inbox)
