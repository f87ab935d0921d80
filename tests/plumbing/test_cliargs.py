"""plumbing.cliargs' argparse types: each refuses a bad value with one message naming the flag."""

import argparse

import pytest

from plumbing.cliargs import auto_or, integer, positive, positive_list, positive_numbers, within


@pytest.mark.parametrize("parse, text, want", [
    (positive("--duration-s"), "2.5", 2.5),
    (positive_list("--velocity"), "0.1, 0.2", [0.1, 0.2]),
    (integer("--load-cores", 0, 64), "3", 3),
    (within("--known-position-m", 0.1, "m"), "-0.05", -0.05),
    (positive_numbers("speeds", "m/s", items="speeds in m/s"), "0.1,,2", [0.1, 2.0]),
    (positive_numbers("tap velocities", "m/s", none=True), "None", []),
    (auto_or("--order", int, "an integer"), "auto", "auto"),
    (auto_or("--delay", float, "a number of seconds"), "1e-4", 1e-4),
])
def test_good_values(parse, text, want):
    assert parse(text) == want


@pytest.mark.parametrize("parse, text, message", [
    (positive("--rate-hz"), "fast", "--rate-hz must be a number, got 'fast'"),
    (positive("--rate-hz"), "nan", "--rate-hz must be > 0, got 'nan'"),
    (positive_list("--velocity"), "0.1,-2", "--velocity must be > 0, got '-2'"),
    (integer("--samples", 10, 100_000), "9", "--samples must be 10..100000, got '9'"),
    (integer("--samples", 10, 100_000), "1.5", "--samples must be an integer, got '1.5'"),
    (within("--known-position-m", 0.1, "m"), "0.2", "--known-position-m must be within +-0.1 m, got '0.2'"),
    (positive_numbers("speeds", "m/s", items="speeds in m/s"), "1,x", "expected comma-separated speeds in m/s, got '1,x'"),
    (positive_numbers("speeds", "m/s", items="speeds in m/s"), "", "speeds must be > 0 m/s, got ''"),
    (positive_numbers("tap velocities", "m/s", none=True), "0.1,0", "tap velocities must be > 0 m/s, got '0.1,0'"),
    (auto_or("--order", int, "an integer"), "many", "--order must be 'auto' or an integer, got 'many'"),
])
def test_bad_values_name_the_flag(parse, text, message):
    with pytest.raises(argparse.ArgumentTypeError) as exc:
        parse(text)
    assert str(exc.value) == message
