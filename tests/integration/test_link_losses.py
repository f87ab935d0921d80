"""A streaming session survives isolated lost/corrupt frames and stops, zeroed, on a dead link (issue 15).

The emulator runs the firmware protocol on a real pty with scripted faults on its device -> host frames.
"""

import json
import time

from devices.firmware.emulator import start_emulator
from renderer.__main__ import main as renderer_main
from tests.support.stalls import run_stalled


def _run(spec, out, tmp_path, capsys, duration_s, overrun_s="0.2"):
    cfg = tmp_path / "cfg.toml"
    # a loaded CI machine can stall this process for >20 ms; widen the host loop's own watchdog so the test
    # checks the link's loss handling, not the scheduler (the device watchdog stays 100 ms)
    cfg.write_text(f"watchdog_overrun_s = {overrun_s}\n")
    code = renderer_main(["run", "--in-process", "--device", spec, "--duration", str(duration_s), "--transient",
                          "pulse", "--config", str(cfg), "--out", str(out)])
    printed = capsys.readouterr()
    return code, printed.out + printed.err   # the error line too: a failed run's assertion shows why it stopped


def test_one_drop_in_200_and_one_corruption_in_500_complete_10_s_at_1_khz(tmp_path, capsys):
    for attempt in range(3):
        out = tmp_path / f"run{attempt}"
        port, handle = start_emulator("streaming", "drop_every=200,corrupt_every=500", process=False,
                                      taps_m_s=(0.05, 0.1, 0.2))
        try:
            # loaded machine: a reply later than 20 ms (default 5 ms) counts as lost, like the widened watchdog
            code, stdout = _run(f"serial:{port}?loss_timeout_s=0.02", out, tmp_path, capsys, 10,
                                overrun_s="0.5")  # 10 s on a shared machine: stalls of ~0.3 s were seen
            emu = dict(handle.emulator.stats)
        finally:
            handle.stop()
        if code == 0 or not run_stalled(out):
            break
        # the machine stalled this process (the emulator runs in it) past the loss timeout, and the frames
        # late after it made 10 losses in a row (a 41 ms gap with two suites on 2 cores): the stop rule acted as
        # its own tests say. The run again: a run without a stall must pass
    assert code == 0, stdout
    run = json.loads((out / "run.json").read_text())
    assert run["stop_reason"] == "duration" and run["rate_hz"] == 1000.0 and run["ticks"] == 10000
    link = run["link"]
    # the script: every 200th frame dropped, every 500th corrupted (of ~10000 the device sent)
    assert emu["frames_out"] >= 9900, emu
    assert 45 <= emu["dropped"] <= 52 and 18 <= emu["corrupted"] <= 21, emu
    assert link["crc_errors"] == emu["corrupted"], (link, emu)
    # a dropped or discarded frame shows as a gap in the device's sequence numbers (the last may be in flight)
    assert emu["dropped"] + emu["corrupted"] - 2 <= link["seq_gaps"] <= emu["dropped"] + emu["corrupted"], (link, emu)
    # every injected loss is counted; a reply late beyond loss_timeout_s on a loaded machine counts too
    assert link["losses"] >= emu["dropped"] + emu["corrupted"] - 2, (link, emu)
    assert link["losses"] < 0.05 * 10000 and link["max_consecutive_losses"] < 10
    assert link["frames_tx"] >= 10000 and link["frames_rx"] >= 10000 - link["losses"] - 5
    assert 0 < link["rtt_median_s"] <= link["rtt_p99_s"] <= link["rtt_max_s"]
    assert link["longest_gap_s"] >= 0.001
    assert "link: " in stdout and " lost " in stdout and "round trip median/p99/max" in stdout


def _burst_run(path, capsys):
    """One streaming run into the emulator's 50-frame drop burst; (run.json, emulator, output after)."""
    port, handle = start_emulator("streaming", "drop_burst_at=2000,drop_burst=50", process=False,
                                  taps_m_s=(0.05,))
    emu = handle.emulator
    try:
        _run(f"serial:{port}", path, path.parent, capsys, 10)
        run = json.loads((path / "run.json").read_text())
        # the emulator thread may not have read the host's last frames yet when the run returns (a loaded
        # machine): wait until it has taken every frame the host sent (the last is the zero) before looking
        deadline = time.monotonic() + 60
        while emu.stats["frames_in"] < run["link"]["frames_tx"] and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emu.stats["frames_in"] == run["link"]["frames_tx"], (emu.stats, run["link"])
        applied_after = emu.applied_A
    finally:
        handle.stop()
    return run, emu, applied_after


def test_50_consecutive_losses_stop_with_zero_output_within_the_watchdog_period(tmp_path, capsys):
    # The emulator is a thread of this process (its counters are read below): on a loaded machine it can be
    # starved of the GIL for the host's 10 x 5 ms before its burst even begins, and the host then stops on
    # those losses, rightly, but not on the burst this test is about. Likewise a reply late by more than the
    # host's 5 ms just before the burst starts the host's streak one frame early (the late reply then arrives
    # and is counted stale), and the host stops after 9 of the burst's frames. Such runs are checked for the
    # same stop and tried again; one of three must be the burst's alone.
    for attempt in range(3):
        run, emu, applied_after = _burst_run(tmp_path / f"run{attempt}", capsys)
        assert run["stop_reason"] == "disconnected", (run["stop_reason"], run["error"])
        assert "10 state frames lost in a row" in run["error"]
        if emu.burst_started is None:
            continue
        if emu.cmds_after_burst == 10:
            break
        # only a late reply (seen by the host as stale) may shorten the burst's share of the streak
        assert emu.cmds_after_burst < 10 and run["link"]["stale_states"] > 0, (emu.cmds_after_burst, run["link"])
    else:
        raise AssertionError("in 3 runs the host never stopped on the emulator's burst alone (starved every time)")
    assert applied_after == 0.0
    # the host's last command after the burst began was a zero, sent at its 10th lost frame: counted in frames,
    # not wall time (the host's 10 loss timeouts of 5 ms are 50 ms of its own clock, within the device's 100 ms
    # watchdog period by design; on a loaded machine the wall time between them is the scheduler's, and the
    # device's own watchdog is what guards a host that is not scheduled)
    _, i_last = emu.last_cmd_after_burst
    link = run["link"]
    assert i_last == 0.0 and emu.cmds_after_burst == link["max_consecutive_losses_allowed"] == 10, \
        (i_last, emu.cmds_after_burst)
    assert link["loss_timeout_s"] * link["max_consecutive_losses_allowed"] < emu.watchdog_ms * 1e-3 / 1.5
    assert run["link"]["max_consecutive_losses"] == 10 and run["ticks"] < 3000
