"""The shared checks of the config dataclasses (plumbing/validation.py) and their messages in use."""

import pytest

from devices.identify.sweep import SweepConfig
from analysis.config import AnalysisConfig
from plumbing.validation import (dataclass_from_dict, is_finite_number, load_dataclass_file, require_choice,
                                 require_int, require_number, require_positive, shown_value)
from renderer.config import RendererConfig
from renderer.demo.config import DemoConfig
from renderer.homing import HomingConfig
from renderer.teleop.session import TeleopConfig
from stimuli.hfam.settings import BuildSettings, PipelineSettings
from study.session.config import ProtocolConfig


class _Cfg:
    a_s = 1.5
    b_hz = 0.0


@pytest.mark.parametrize("value, ok", [(1, True), (0.5, True), (0, False), (-1.0, False), (float("nan"), False),
                                       (float("inf"), False), (True, False), ("2", False), (None, False)])
def test_require_positive(value, ok):
    cfg = _Cfg()
    cfg.b_hz = value
    if ok:
        require_positive(cfg, "a_s", "b_hz")
    else:
        with pytest.raises(ValueError, match=r"^x\.b_hz must be a positive finite number, got "):
            require_positive(cfg, "a_s", "b_hz", prefix="x.")


def test_require_number_bounds_and_optional():
    assert require_number("k", 0.0, minimum=0.0) == 0.0
    with pytest.raises(ValueError, match=r"^k must be > 0.0, got 0.0$"):
        require_number("k", 0.0, minimum=0.0, strict=True)
    with pytest.raises(ValueError, match=r"^k must be <= 1, got 2$"):
        require_number("k", 2, maximum=1)
    assert require_number("k", None, optional=True) is None
    with pytest.raises(ValueError, match=r"^k must be a finite number, got None$"):
        require_number("k", None)


@pytest.mark.parametrize("value, finite", [(1, True), (-2.5, True), (10 ** 300, True), (10 ** 400, False),
                                           (-(10 ** 400), False), (float("nan"), False), (float("-inf"), False),
                                           (True, False), ("1", False), (None, False)])
def test_is_finite_number_never_overflows(value, finite):
    # a JSON integer with hundreds of digits made math.isfinite raise OverflowError in five readers
    assert is_finite_number(value) is finite
    if finite:
        assert require_number("k", value) == value
    else:
        with pytest.raises(ValueError, match=r"^k must be a finite number, got "):
            require_number("k", value)


def test_shown_value_says_a_huge_integer_in_words():
    assert shown_value(10 ** 400) == "an integer too large for a float"
    assert shown_value(10 ** 300) == repr(10 ** 300) and shown_value("x") == "'x'" and shown_value(True) == "True"
    with pytest.raises(ValueError, match=r"^k must be a finite number, got an integer too large for a float$"):
        require_number("k", 10 ** 400)


def test_require_int_rejects_bools_and_floats():
    assert require_int("n", 3, minimum=1, maximum=5) == 3
    for bad in (True, 3.0, 0, 6):
        with pytest.raises(ValueError, match=r"^n must be an integer 1\.\.5, got "):
            require_int("n", bad, minimum=1, maximum=5)


@pytest.mark.parametrize("make, message", [
    (lambda: SweepConfig(duration_s=-1.0), r"^sweep duration_s must be a positive finite number, got -1\.0"),
    (lambda: SweepConfig(repetitions=0), r"^sweep repetitions must be an integer >= 1, got 0"),
    (lambda: HomingConfig(kp_N_m=float("nan")), r"^homing\.kp_N_m must be a positive finite number, got nan"),
    (lambda: HomingConfig(kd_N_s_m=-1.0), r"^homing\.kd_N_s_m must be >= 0\.0, got -1\.0"),
    (lambda: BuildSettings(smooth_order=9), r"^BuildSettings\.smooth_order must be an integer 1\.\.8, got 9"),
    (lambda: ProtocolConfig(tap_window_s=True), r"^tap_window_s must be a positive finite number, got True"),
    (lambda: RendererConfig(stiffness_N_m=-5.0), r"^stiffness_N_m must be >= 0\.0, got -5\.0"),
    (lambda: RendererConfig(until_every=0), r"^until_every must be an integer >= 1, got 0"),
])
def test_config_classes_use_the_shared_checks(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_strict_maximum_and_choices():
    assert require_number("alpha", 0.999, minimum=0.0, strict=True, maximum=1.0, strict_maximum=True) == 0.999
    with pytest.raises(ValueError, match=r"^alpha must be < 1.0, got 1.0$"):
        require_number("alpha", 1.0, maximum=1.0, strict_maximum=True)
    assert require_number("gain", 1.0, maximum=1.0) == 1.0
    assert require_choice("group", "all", ("both", "all")) == "all"
    with pytest.raises(ValueError, match=r"^cfg.group must be one of both, all, got 'none'$"):
        require_choice("group", "none", ("both", "all"), prefix="cfg.")


@pytest.mark.parametrize("make, message", [
    (lambda: AnalysisConfig(alpha=1.0), r"--alpha must be < 1.0, got 1.0"),
    (lambda: AnalysisConfig(margin=float("nan")), r"--margin must be a finite number, got nan"),
    (lambda: AnalysisConfig(group="some"), r"--group must be one of both, all, experienced, got 'some'"),
    (lambda: TeleopConfig(mu=0.0), r"mu must be a positive finite number, got 0.0"),
    (lambda: TeleopConfig(lam=float("inf")), r"lam must be a finite number, got inf"),
    (lambda: TeleopConfig(controller="p"), r"controller must be one of .*, got 'p'"),
    (lambda: PipelineSettings(refine_gain=1.5), r"refine_gain must be <= 1.0, got 1.5"),
    (lambda: PipelineSettings(record_velocities_m_s=(0.1, float("nan"))),
     r"record_velocities_m_s\[1\] must be a finite number, got nan"),
    (lambda: DemoConfig(grips_N=(1.0, -2.0)), r"demo grips_N\[1\] must be > 0.0, got -2.0"),
])
def test_more_config_classes_use_the_shared_checks(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_a_config_file_error_names_the_file_and_the_key(tmp_path):
    f = tmp_path / "protocol.toml"
    f.write_text("repetitions = 0\n", encoding="utf-8")
    with pytest.raises(ValueError, match=rf"^{f}: .*repetitions.*0"):
        load_dataclass_file(f, ProtocolConfig, "protocol")
    f.write_text("repetitons = 3\n", encoding="utf-8")
    with pytest.raises(ValueError, match=rf"^{f}: unknown protocol key\(s\) \['repetitons'\]; valid keys: .*'repetitions'"):
        load_dataclass_file(f, ProtocolConfig, "protocol")
    f.write_text("repetitions = [", encoding="utf-8")
    with pytest.raises(ValueError, match=rf"^{f}: cannot parse"):
        load_dataclass_file(f, ProtocolConfig, "protocol")
    with pytest.raises(FileNotFoundError, match="protocol file .*missing.toml not found"):
        load_dataclass_file(tmp_path / "missing.toml", ProtocolConfig, "protocol")
    assert load_dataclass_file(None, ProtocolConfig, "protocol", {"repetitions": 2, "seed": None}).repetitions == 2
    with pytest.raises(ValueError, match=r"^session.json: protocol: .*repetitions"):
        dataclass_from_dict(ProtocolConfig, {"repetitions": -1}, "protocol", "session.json: protocol")


def test_a_refused_override_names_the_command_line_and_a_refused_file_value_names_the_file(tmp_path):
    good = tmp_path / "good.toml"
    good.write_text("tap_window_s = 2.0\n")
    with pytest.raises(ValueError, match=r"^command line: tap_window_s must be <= 60.0, got 1e\+308"):
        load_dataclass_file(good, ProtocolConfig, "protocol", {"tap_window_s": 1e308})
    bad = tmp_path / "bad.toml"
    bad.write_text("tap_window_s = 1e308\nfirst_tap_timeout_s = -1.0\n")
    # the file's own values are refused (with or without the flag): the file is named
    with pytest.raises(ValueError, match=r"^.*bad\.toml: "):
        load_dataclass_file(bad, ProtocolConfig, "protocol", {"tap_window_s": 2.0})
    # a flag that replaces the file's only bad value makes the whole accepted
    bad.write_text("tap_window_s = 1e308\n")
    assert load_dataclass_file(bad, ProtocolConfig, "protocol", {"tap_window_s": 2.0}).tap_window_s == 2.0
