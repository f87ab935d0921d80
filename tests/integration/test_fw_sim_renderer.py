"""`renderer run` against the real AVR firmware on simavr (device string fw-sim, issue 19)."""


def test_renderer_run_on_the_real_firmware(tmp_path, capsys):
    """`renderer run --device fw-sim?mode=on-device`: the renderer's own command against the AVR firmware."""
    import csv
    import json

    from renderer.__main__ import main as renderer_main

    cfg = tmp_path / "cfg.toml"
    cfg.write_text("watchdog_overrun_s = 0.2\n")
    out = tmp_path / "run"
    code = renderer_main(["run", "--in-process", "--device", "fw-sim?mode=on-device&pace=fast", "--duration", "1.5",
                          "--transient", "pulse", "--config", str(cfg), "--out", str(out)])
    stdout = capsys.readouterr().out
    assert code == 0, stdout
    run = json.loads((out / "run.json").read_text())
    assert run["rate_hz"] == 4000.0 and run["stop_reason"] == "duration"
    assert run["device"]["name"] == "hapkit-paddle"
    with open(out / "events.csv") as fh:
        events = list(csv.DictReader(fh))
    assert len(events) >= 2 and all(e["transient"] == "pulse" for e in events)  # the hand's taps, on board

