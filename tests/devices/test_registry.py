"""Device strings are checked before anything is set up; identify's default grips span the device's range."""

import pytest

from devices import check_device_spec, make_device
from devices.cli_identify import default_grip_levels
from tests.support.cli import run_cli


@pytest.mark.parametrize("spec, kind", [("sim", "sim"), ("sim:lti", "sim"), ("serial:/dev/ttyACM0", "serial"),
                                        ("serial:/dev/pts/3?mode=on-device&timeout_s=0.05", "serial"),
                                        ("hid:16c0:0486", "hid")])
def test_valid_device_strings(spec, kind):
    assert check_device_spec(spec) == kind


@pytest.mark.parametrize("spec", ["bogus", "serial:", "hid:16c0", "hid:zz:0486", "usb:1:2", "serial:/dev/x?mode"])
def test_malformed_device_strings_name_the_string(spec):
    with pytest.raises(ValueError) as err:
        check_device_spec(spec)
    assert repr(spec) in str(err.value)
    with pytest.raises(ValueError):
        make_device(spec)


def test_unknown_form_lists_the_valid_forms():
    with pytest.raises(ValueError, match=r"valid forms: sim, sim:joystick, sim:onedof, sim:lti, .*serial:<port>, hid:<vid>:<pid>"):
        check_device_spec("bogus")


def test_default_identify_grips_span_the_sim_grip_range():
    info = make_device("sim").info
    levels = default_grip_levels(info.grip_range_N)
    assert levels[0] == info.grip_range_N[0] and levels[-1] == info.grip_range_N[1]
    assert levels == (0.0, 1.0, 2.0, 3.0, 5.0, 10.0)
    assert default_grip_levels((0.0, 2.5)) == (0.0, 1.0, 1.25, 2.0, 2.5)


def test_study_reports_a_bad_device_string_first(tmp_path, capsys):
    proc = run_cli(capsys, "study", "run", "--device", "bogus", "--participant", "keyboard",
                   "--subject", "X1", "--age", "20", "--gender", "female", "--handedness", "right",
                   "--experience", "few", "--out", tmp_path / "data")
    assert proc.returncode == 2
    assert "unknown device string 'bogus'" in proc.stderr
    assert "Traceback" not in proc.stderr
