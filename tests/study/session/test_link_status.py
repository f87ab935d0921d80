"""The operator page's link line comes from the device's own link counters (issue 14 item 7)."""

from devices import make_device
from devices.firmware.emulator import start_emulator
from study.session.apparatus import link_summary


def _exercise(dev, n: int) -> None:
    for _ in range(n):
        dev.read()
        dev.command(0.0)


def test_sim_device_has_no_link():
    with make_device("sim").open() as dev:
        assert link_summary(dev) == "sim (no link)"


def _link_after(faults, n: int, loss_timeout_s: float = 0.05):
    """``(link_stats, link_summary)`` after ``n`` read/command cycles over the emulator with ``faults``."""
    port, handle = start_emulator("streaming", faults, process=False, taps_m_s=(0.05,))
    try:
        with make_device(f"serial:{port}?loss_timeout_s={loss_timeout_s}").open() as dev:
            _exercise(dev, n)
            return dev.link_stats(), link_summary(dev)
    finally:
        handle.stop()


def test_clean_serial_link_reads_ok_with_its_round_trip():
    # a reply later than 0.95 s is lost: the emulator runs in this process, which a loaded machine stalled past
    # 50 ms (2 replies counted lost with two suites on 2 cores)
    stats, line = _link_after(None, 300, loss_timeout_s=0.95)
    assert stats["crc_errors"] == 0 and stats["losses"] == 0, stats
    assert line.startswith("ok · rtt p99 ") and line.endswith(" ms"), line
    p99_ms = float(line.split("rtt p99 ")[1].split(" ms")[0])
    assert abs(p99_ms - stats["rtt_p99_s"] * 1e3) <= 0.05 + 1e-9 and p99_ms > 0


def test_corrupted_frames_show_as_faults_with_their_counts():
    stats, line = _link_after("corrupt_every=50", 400)
    assert stats["crc_errors"] >= 5, stats
    assert line.startswith("FAULTS: "), line
    assert f"{stats['crc_errors']} CRC" in line and f"{stats['losses']} lost" in line, (line, stats)
