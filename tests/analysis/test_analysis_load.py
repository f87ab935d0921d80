"""Loading and validation: bad input gives a clear error naming file and line."""

from __future__ import annotations

import json
import warnings
import re

import numpy as np
import pytest

from analysis.load import TRIAL_COLUMNS, load_study
from analysis.synthetic import write_synthetic_study

pytestmark = pytest.mark.filterwarnings("ignore::analysis.load.AnalysisWarning")


@pytest.fixture()
def small(tmp_path):
    write_synthetic_study(tmp_path, 3, seed=11, p_invalid=0.2)
    return tmp_path


def _lines(path):
    return path.read_text().splitlines()


def _write(path, lines):
    path.write_text("\n".join(lines) + "\n")


def _set_field(path, line_no, column, value):
    """Set one field (1-based line number) of a trials.csv written by the generator (no quoting)."""
    lines = _lines(path)
    idx = TRIAL_COLUMNS.index(column)
    fields = lines[line_no - 1].split(",")
    fields[idx] = value
    lines[line_no - 1] = ",".join(fields)
    _write(path, lines)


def _first_line(path, phase="testing", valid="true"):
    for i, line in enumerate(_lines(path)[1:], start=2):
        f = line.split(",")
        if f[1] == phase and f[TRIAL_COLUMNS.index("valid")] == valid:
            return i
    raise AssertionError("no such row")


def test_loads_typed_rows(small):
    study = load_study(small)
    t = study.trials
    assert len(study.subjects) == 3 and study.catalog[:2] == ("wood", "wood_on_foam")
    assert t["valid"].dtype == bool and t["trial"].dtype == np.int64
    valid_testing = t[(t["phase"] == "testing") & t["valid"]]
    assert len(valid_testing) == 3 * 12 * 3
    assert valid_testing["rating"].between(1, 7).all()
    assert (t["line"] >= 2).all() and t["file"].str.endswith("trials.csv").all()
    assert not t.loc[t["rejected"], "rating"].notna().any()  # rejected attempts have no rating


def test_empty_folder_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="no subject folders"):
        load_study(tmp_path)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_study(tmp_path / "nope")


def test_misspelled_column_names_file_line_and_guess(small):
    path = small / "S002" / "trials.csv"
    lines = _lines(path)
    lines[0] = lines[0].replace("rating", "ratng")
    _write(path, lines)
    with pytest.raises(ValueError, match=re.escape(f"{path}:1: missing column(s) 'rating' (found 'ratng'")):
        load_study(small)


def test_missing_column(small):
    path = small / "S001" / "trials.csv"
    lines = [",".join(f for j, f in enumerate(line.split(",")) if j != TRIAL_COLUMNS.index("saturated"))
             for line in _lines(path)]
    _write(path, lines)
    with pytest.raises(ValueError, match=re.escape(f"{path}:1: missing column(s) 'saturated'")):
        load_study(small)


@pytest.mark.parametrize("value", ["9", "0", "", "4.5"])
def test_rating_outside_range_on_valid_attempt(small, value):
    path = small / "S003" / "trials.csv"
    line = _first_line(path)
    _set_field(path, line, "rating", value)
    with pytest.raises(ValueError, match=re.escape(f"{path}:{line}: column 'rating': value {value!r}")):
        load_study(small)


def test_rating_outside_range_on_invalid_attempt_is_ignored(small):
    path = small / "S003" / "trials.csv"
    line = _first_line(path, valid="false")
    _set_field(path, line, "rating", "")
    load_study(small)


def test_duplicated_attempt_names_both_lines(small):
    path = small / "S001" / "trials.csv"
    lines = _lines(path)
    line = _first_line(path)
    _write(path, lines + [lines[line - 1]])
    with pytest.raises(ValueError, match=re.escape(f"{path}:{line}, {path}:{len(lines) + 1}")):
        load_study(small)


def test_unparsable_session_json_names_line(small):
    path = small / "S002" / "session.json"
    text = path.read_text().replace('"experience": "', '"experience" "', 1)
    path.write_text(text)
    line = next(i for i, ln in enumerate(text.splitlines(), start=1) if '"experience" "' in ln)
    with pytest.raises(ValueError, match=re.escape(f"{path}:{line}: not valid JSON")):
        load_study(small)


def test_bad_values_name_file_line_column(small):
    path = small / "S001" / "trials.csv"
    _set_field(path, 5, "saturated", "yes")
    with pytest.raises(ValueError, match=re.escape(f"{path}:5: column 'saturated': value 'yes' is not true|false")):
        load_study(small)
    write_synthetic_study(small, 3, seed=11)
    _set_field(path, 7, "sample", "marble")
    with pytest.raises(ValueError, match=re.escape(f"{path}:7: column 'sample': value 'marble' is not in the catalog")):
        load_study(small)
    write_synthetic_study(small, 3, seed=11)
    _set_field(path, 4, "phase", "warmup")
    with pytest.raises(ValueError, match=re.escape(f"{path}:4: column 'phase'")):
        load_study(small)
    write_synthetic_study(small, 3, seed=11)
    _set_field(path, 3, "trial", "1e20")  # was reported as value -9223372036854775808 (int64 wrap)
    with pytest.raises(ValueError, match=re.escape(f"{path}:3: column 'trial': value '1e20' is out of range")):
        load_study(small)
    write_synthetic_study(small, 3, seed=11)
    line = _first_line(path)
    _set_field(path, line, "incoming_velocities_m_s", "0.1;fast")
    from analysis.pipeline import analyse
    with pytest.raises(ValueError, match=re.escape(f"{path}:{line}: column 'incoming_velocities_m_s': '0.1;fast'")):
        analyse(small)


def test_session_json_keys_are_checked(small):
    path = small / "S001" / "session.json"
    info = json.loads(path.read_text())
    info["experience"] = "expert"
    path.write_text(json.dumps(info))
    with pytest.raises(ValueError, match=re.escape(f"{path}: key 'experience'")):
        load_study(small)
    del info["catalog"]
    path.write_text(json.dumps(info))
    with pytest.raises(ValueError, match=re.escape(f"{path}: missing key 'catalog'")):
        load_study(small)


def test_missing_trials_file(small):
    (small / "S002" / "trials.csv").unlink()
    with pytest.raises(FileNotFoundError, match="S002/trials.csv is missing"):
        load_study(small)


def test_catalog_as_list_of_names(small):
    for sess in small.glob("*/session.json"):
        info = json.loads(sess.read_text())
        info["catalog"] = [c["name"] for c in info["catalog"]]
        sess.write_text(json.dumps(info))
    study = load_study(small)
    assert study.kinds["foam"] == "real" and study.kinds["hfam_firm"] == "virtual"


def test_torn_last_line_is_left_out_with_warning(small):
    from analysis.load import AnalysisWarning
    path = small / "S001" / "trials.csv"
    text = path.read_text()
    n_rows = len(text.splitlines()) - 1
    path.write_text(text + "S001,testing,99,1,wood,real,5,fal")
    with pytest.warns(AnalysisWarning, match="torn last line"):
        study = load_study(small)
    assert (study.trials["subject"] == "S001").sum() == n_rows


def test_wrong_field_count_mid_file_names_line(small):
    path = small / "S001" / "trials.csv"
    lines = _lines(path)
    lines[4] = lines[4] + ",extra"
    _write(path, lines)
    with pytest.raises(ValueError, match=re.escape(f"{path}:5: 19 fields, header has 18")):
        load_study(small)


def test_blank_and_crlf_lines_keep_line_numbers(small):
    path = small / "S002" / "trials.csv"
    lines = _lines(path)
    line = _first_line(path)
    fields = lines[line - 1].split(",")
    fields[TRIAL_COLUMNS.index("rating")] = "8"
    lines[line - 1] = ",".join(fields)
    path.write_bytes(("\r\n".join(lines[:2] + [""] + lines[2:]) + "\r\n").encode())
    with pytest.raises(ValueError, match=re.escape(f"{path}:{line + 1}: column 'rating'")):
        load_study(small)


def test_inconsistent_rows_name_line(small):
    path = small / "S001" / "trials.csv"
    line = _first_line(path)
    _set_field(path, line, "saturated", "true")
    with pytest.raises(ValueError, match=re.escape(f"{path}:{line}: column 'valid': value 'true' is true on an "
                                                   "attempt marked")):
        load_study(small)
    write_synthetic_study(small, 3, seed=11)
    lines = _lines(path)
    fields = lines[line - 1].split(",")
    fields[TRIAL_COLUMNS.index("kind")] = "virtual" if fields[TRIAL_COLUMNS.index("kind")] == "real" else "real"
    lines[line - 1] = ",".join(fields)
    _write(path, lines)
    with pytest.raises(ValueError, match=re.escape(f"{path}:{line}: column 'kind'")):
        load_study(small)
    write_synthetic_study(small, 3, seed=11)
    _set_field(path, line, "attempt", "0")
    with pytest.raises(ValueError, match=re.escape(f"{path}:{line}: column 'attempt': value 0 must be >= 1")):
        load_study(small)


def test_fast_reader_gives_the_exact_readers_table(tmp_path):
    """The one-pass typed reader (plain files) and the exact per-file reader give identical studies."""
    import pandas as pd

    import analysis.load as L

    write_synthetic_study(tmp_path, 6, seed=5, missing={"S002": ["foam"]}, unfinished=["S003"])
    assert L._fast_trials(sorted(tmp_path.iterdir())) is not None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fast = L.load_study(tmp_path)
        orig = L._fast_trials, L._fast_lists
        try:
            L._fast_trials, L._fast_lists = (lambda folders: None), (lambda cells: None)
            exact = L.load_study(tmp_path)
        finally:
            L._fast_trials, L._fast_lists = orig
    pd.testing.assert_frame_equal(fast.trials, exact.trials)
    pd.testing.assert_frame_equal(fast.subjects, exact.subjects)
    assert fast.warnings == exact.warnings and fast.catalog == exact.catalog
    for col in L.LIST_COLUMNS:
        np.testing.assert_array_equal(fast.taps[col][0], exact.taps[col][0])
        np.testing.assert_array_equal(fast.taps[col][1], exact.taps[col][1])


def test_sessions_read_in_another_process_give_the_same_study(tmp_path):
    """submit_sessions (the report's drawing process reads the session files): same study, warnings, errors."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    import pandas as pd

    import analysis.load as L

    def load(*args):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            study = L.load_study(*args)
        return study, [str(w.message) for w in caught if issubclass(w.category, L.AnalysisWarning)]

    write_synthetic_study(tmp_path, 6, seed=5, missing={"S002": ["foam"]}, unfinished=["S003"])
    catalog = json.loads((tmp_path / "S005" / "session.json").read_text())
    catalog["catalog"] = catalog["catalog"][::-1]              # a catalog differing from the first session's
    (tmp_path / "S005" / "session.json").write_text(json.dumps(catalog))
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        (here, here_warned), (there, there_warned) = load(tmp_path), load(tmp_path, L.submit_sessions(tmp_path, pool))
        assert len(here.warnings) == 2 and there.warnings == here.warnings and there_warned == here_warned
        pd.testing.assert_frame_equal(there.trials, here.trials)
        pd.testing.assert_frame_equal(there.subjects, here.subjects)
        assert there.catalog == here.catalog and there.kinds == here.kinds
        for col in L.LIST_COLUMNS:
            for a, b in zip(there.taps[col], here.taps[col]):
                np.testing.assert_array_equal(a, b)
        (tmp_path / "S004" / "session.json").write_text('{"subject": "S004",')
        with pytest.raises(ValueError) as exact:
            L.load_study(tmp_path)
        with pytest.raises(ValueError) as elsewhere:
            L.load_study(tmp_path, L.submit_sessions(tmp_path, pool))
        assert str(elsewhere.value) == str(exact.value) and "S004/session.json" in str(exact.value)
        with pytest.raises(ValueError, match="sessions submitted for"):
            L.load_study(tmp_path, L.submit_sessions(tmp_path / "S001", pool))


def test_header_lines_only_is_an_error(small):
    for path in small.glob("*/trials.csv"):
        _write(path, _lines(path)[:1])
    with pytest.raises(ValueError, match="the trials.csv files hold no attempts"):
        load_study(small)


@pytest.mark.parametrize("name", ["session.json", "trials.csv"])
@pytest.mark.parametrize("damage,match", [("dir", ": is a directory, expected a file"),
                                          ("nonutf8", r":\d+: not UTF-8 text \(invalid start byte at byte \d+\)")])
def test_report_names_a_directory_or_non_utf8_subject_file(small, capsys, name, damage, match):
    """Audit analysis_{session,trials}_{is_dir,nonutf8}.txt: a raw IsADirectoryError traceback or a codec message
    without the file; now ``python -m analysis report`` exits 2 with one line naming the file (and the line)."""
    from analysis.__main__ import main
    path = small / "S002" / name
    if damage == "dir":
        path.unlink()
        path.mkdir()
    else:
        raw = path.read_bytes()
        at = raw.index(b"\n", raw.index(b"\n") + 1) + 3         # on the third line
        path.write_bytes(raw[:at] + b"\xff" + raw[at + 1:])
    capsys.readouterr()
    assert main(["report", str(small), "--out", str(small.with_name(small.name + "_rep")), "--no-figures"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.fullmatch(re.escape(f"error: {path}") + match, err[0]), err
    if damage == "nonutf8":
        assert err[0].startswith(f"error: {path}:3: ")
