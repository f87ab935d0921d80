"""devices.hardware.threedof: the 3-DOF drivers' shared link rules, on a driver whose replies and clock the
test sets (the adapters themselves are tested against their emulators in test_lab_adapters.py)."""

from __future__ import annotations

import types

import pytest

from devices.base import Status
from devices.hardware import threedof
from devices.hardware.threedof import ThreeAxisDevice, three_axis_info


class _Clock:
    def __init__(self) -> None:
        self.now_s = 1000.0

    def monotonic(self) -> float:
        return self.now_s


class _Link(ThreeAxisDevice):
    """Answers while ``answering``; each transaction first moves the clock on by ``tick_s``."""

    spec_prefix = "test-link"

    def __init__(self, clock: _Clock, tick_s: float, **kwargs) -> None:
        super().__init__(watchdog_ms=0, **kwargs)
        self.info = three_axis_info("test link", 1000.0, (-0.1, -0.1, -0.1), (0.1, 0.1, 0.1), 3.0, 3.0, 2000.0,
                                    1e-5, True, 0)
        self.clock, self.tick_s, self.answering = clock, tick_s, True

    def _open_link(self) -> None:
        pass

    def _close_link(self) -> None:
        pass

    def _transact(self, fx_N, fy_N, fz_N) -> bool:
        self.clock.now_s += self.tick_s
        return self.answering


@pytest.mark.parametrize("tick_s, losses, silence_ms", [
    (0.005, 10, 50),    # a serial link: each lost reply waited the whole 5 ms timeout
    (0.001, 10, 10),    # a servo thread read once per 1 ms host tick (the Touch): 10 losses are 10 ms of silence
    (0.001, 3, 3),
])
def test_the_lost_reply_message_gives_the_silence_as_measured(monkeypatch, tick_s, losses, silence_ms):
    clock = _Clock()
    monkeypatch.setattr(threedof, "time", types.SimpleNamespace(monotonic=clock.monotonic))
    dev = _Link(clock, tick_s, loss_timeout_s=0.1, max_consecutive_losses=losses)
    with dev:
        dev.command_force(0.0, 0.0, 0.5)            # one answered transaction: the last reply
        assert dev.read().status & Status.DISCONNECTED == 0
        dev.answering = False
        for _ in range(losses):
            dev.command_force(0.0, 0.0, 0.5)
        st = dev.read()
    assert st.status & Status.DISCONNECTED
    assert dev.stats["losses"] == losses and dev.stats["max_consecutive_losses"] == losses
    # the last lost transaction found the link dead and tried one last zero (also lost): the silence is counted
    # at the moment the limit was reached
    assert f"{losses} replies lost in a row, no reply for {silence_ms} ms" in st.extra["error"], st.extra["error"]
    assert "a reply later than 100 ms counts as lost" in st.extra["error"]
