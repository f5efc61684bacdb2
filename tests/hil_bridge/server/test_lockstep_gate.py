"""LockstepGate: what a tick owes (answers by step, pings by sim time), stalls and release."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from hil_bridge.server.lockstep import LockstepGate


def _gate(**kw: object) -> LockstepGate:
    args: dict[str, object] = {"lockstep": True, "timeout_s": 0.05, "max_stalls": 3,
                               "start_timeout_s": 0.05, "resend_s": 10.0}
    args.update(kw)
    return LockstepGate(**args)  # type: ignore[arg-type]


def _in_thread(fn: Callable[[], None]) -> threading.Thread:
    t = threading.Thread(target=fn, daemon=True)
    t.start()
    return t


def test_autopilots_owe_their_published_step_swarm_only_when_physics_is_due() -> None:
    gate = _gate(timeout_s=30.0, start_timeout_s=30.0, autopilots=[1, 100])
    gate.published(1, 4, alive=True, every_tick=False)
    gate.published(100, 9, alive=True, every_tick=True)
    gate.on_cmd(100, 9)
    gate.wait(0, physics_due=False)  # glider 1 owes nothing between physics steps
    gate.on_cmd(1, 3)  # an old step does not answer step 4
    waiter = _in_thread(lambda: gate.wait(0, physics_due=True))
    waiter.join(0.1)
    assert waiter.is_alive()
    gate.on_cmd(1, 4)
    waiter.join(5.0)
    assert not waiter.is_alive() and gate.stats()["stalls"] == 0


def test_dead_gliders_owe_nothing_and_silent_ones_stall_then_are_released() -> None:
    gate = _gate(autopilots=[2, 3])
    gate.published(2, 0, alive=False, every_tick=False)
    gate.published(3, 0, alive=True, every_tick=False)
    for _ in range(4):
        gate.wait(0, physics_due=True)
    st = gate.stats()
    assert (st["stalls"], st["stalled_steps"], st["lockstep_released"]) == (3, 3, 1)
    assert st["freewheeling"] == [3]
    gate.on_cmd(3, 0)  # it answers again: waited for again
    gate.published(3, 1, alive=True, every_tick=False)
    assert gate.stats()["freewheeling"] == []
    gate.wait(0, physics_due=True)
    assert gate.stats()["stalls"] == 4
    assert gate.stats()["stalls_by"] == {"glider 3": 4}  # who held the loop up


def test_a_participant_not_heard_yet_gets_the_start_timeout() -> None:
    unheard = _gate(timeout_s=60.0, start_timeout_s=0.2, autopilots=[1])
    unheard.published(1, 0, alive=True, every_tick=True)
    t0 = time.monotonic()
    unheard.wait(0, physics_due=False)
    assert time.monotonic() - t0 >= 0.2 and unheard.stats()["stalls"] == 1
    heard = _gate(timeout_s=0.01, start_timeout_s=60.0, autopilots=[1])
    heard.on_cmd(1, 0)
    heard.published(1, 1, alive=True, every_tick=True)
    waiter = _in_thread(lambda: heard.wait(20, physics_due=False))
    waiter.join(10.0)
    assert not waiter.is_alive() and heard.stats()["stalls"] == 1


def test_sonar_pings_are_owed_at_their_sim_time_and_wait_for_the_servers_echo() -> None:
    gate = _gate(timeout_s=0.1, start_timeout_s=0.1, sonars=[0])
    waiter = _in_thread(lambda: gate.wait(0, physics_due=False))  # ping 0 is due at 0
    waiter.join(0.03)
    assert waiter.is_alive()
    assert gate.on_ping(0, 0, 200)
    waiter.join(5.0)
    assert not waiter.is_alive()
    gate.wait(180, physics_due=False)  # the next ping is due at 200: nothing owed at 180
    # at 200 the head waits for echo 0, which the server still computes: no stall meanwhile
    waiter = _in_thread(lambda: gate.wait(200, physics_due=False))
    waiter.join(0.4)
    assert waiter.is_alive() and gate.stats()["stalls"] == 0
    gate.echo_done(0)  # now the head has timeout_s to send its ping
    waiter.join(5.0)
    assert not waiter.is_alive() and gate.stats()["stalls"] == 1


def test_own_clock_pings_of_a_lockstep_head_are_not_answered() -> None:
    gate = _gate(sonars=[0])
    assert not gate.on_ping(0, 123_456_789, -1)
    assert gate.on_ping(1, 5, -1)  # a sonar that never pinged on sim time: answered
    assert gate.stats()["pings_ignored"] == 1
    realtime = LockstepGate(lockstep=False, timeout_s=1.0, max_stalls=1, start_timeout_s=1.0,
                            sonars=[0])
    assert realtime.on_ping(0, 5, -1)


def test_resend_runs_while_waiting_and_interrupt_ends_the_wait() -> None:
    gate = _gate(timeout_s=30.0, start_timeout_s=30.0, resend_s=0.05, autopilots=[1])
    gate.published(1, 0, alive=True, every_tick=True)
    resends: list[float] = []
    waiter = _in_thread(lambda: gate.wait(0, physics_due=False,
                                          resend=lambda: resends.append(time.monotonic())))
    waiter.join(0.3)
    gate.interrupt()
    waiter.join(5.0)
    assert not waiter.is_alive()
    assert len(resends) >= 2 and gate.stats()["stalls"] == 0
    gate.wait(0, physics_due=False)  # interrupted for good: returns at once
