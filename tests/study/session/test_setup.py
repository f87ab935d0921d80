"""The checks before a session starts (study.session.setup): a subject never overwritten, bad input refused."""

import os
import stat
import subprocess

import pytest

from study.session.store import check_subject_id

from tests.support.study import run_study, write


@pytest.mark.parametrize("bad", ["../x", "a/b", "a\\b", "..", "", " S1", "S 1", ".hidden", "x" * 65])
def test_subject_ids_with_path_characters_refused(bad):
    with pytest.raises(ValueError, match="subject id"):
        check_subject_id(bad)


def test_bad_input_refused_before_start(tmp_path, capsys):
    data = tmp_path / "DATA"

    def refused(*args, match):
        assert run_study(*args) == 2
        err = capsys.readouterr().err
        assert match in err, err
        assert not (data / "S9").exists()

    base = ["--seed", 1, "--out", data]
    refused("--subject", "../S9", *base, match="subject id")
    refused("--subject", "S9", *base, "--repetitions", 0, match="repetitions must be an integer 1..100")
    refused("--subject", "S9", *base, "--samples", "wood,marble", match="unknown sample(s) ['marble']")
    # a catalog whose real sample does not exist in the sim, and one whose HFAM library is missing
    cat = write(tmp_path / "cat.toml", '[[sample]]\nname = "wood"\nkind = "real"\nstiffness_N_m = 70000.0\n'
                'transient = "none"\nreal_sample = "marble"\n')
    refused("--subject", "S9", *base, "--catalog", cat, match="unknown sim sample real_sample='marble'")
    cat = write(tmp_path / "cat2.toml", '[[sample]]\nname = "wood"\nkind = "real"\nstiffness_N_m = 70000.0\n'
                'transient = "none"\nreal_sample = "wood"\n[[sample]]\nname = "h"\nkind = "virtual"\n'
                'stiffness_N_m = 680.0\ntransient = "hfam"\nlibrary = "nowhere/lib.npz"\n')
    refused("--subject", "S9", *base, "--catalog", cat, match="lib.npz")
    refused("--subject", "S9", *base, "--catalog", cat, match="does not exist")
    refused("--subject", "S9", *base, "--protocol", write(tmp_path / "p.toml", "tap_window = 5\n"),
            match="unknown protocol key(s) ['tap_window']")
    refused("--subject", "S9", *base, "--participant", "keyboard", match="--age")
    refused("--subject", "S9", "--out", data, "--device", "serial:/dev/null", match="needs a sim device")


def test_unwritable_folder_refused(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    if os.geteuid() == 0:   # root ignores permission bits; an immutable directory refuses root too
        subprocess.run(["chattr", "+i", str(ro)], check=True)
    else:
        ro.chmod(stat.S_IRUSR | stat.S_IXUSR)
    try:
        assert run_study("--subject", "S1", "--out", ro, "--seed", 1) == 2
        assert f"data folder {ro} is not writable" in capsys.readouterr().err
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(ro)], check=True)
    assert not (ro / "S1").exists()


def test_data_folder_under_a_file_refused(tmp_path, capsys):
    f = write(tmp_path / "plainfile", "x")
    assert run_study("--subject", "S1", "--out", f / "DATA", "--seed", 1) == 2
    assert "cannot be created" in capsys.readouterr().err


@pytest.mark.parametrize("name,content,option,match", [
    ("num.json", b"5", "--protocol", ": a protocol file must hold a table/object of settings, got int"),
    ("list.json", b"[1, 2]", "--protocol", ": a protocol file must hold a table/object of settings, got list"),
    ("nonutf.toml", b"repetitions = 2\n# \xff\n", "--protocol",
     ":2: protocol file is not UTF-8 text (invalid start byte at byte 18)"),
    ("latin1.toml", '[[sample]]\nname = "caf\u00e9"\n'.encode("latin-1"), "--catalog",
     ":2: catalog is not UTF-8 text (invalid continuation byte at byte 22)"),
    # audit protocol_mask_str.txt: "must be real number, not str" named no key
    ("mask_str.toml", b'masking_level_dbfs = "loud"\n', "--protocol",
     ": masking_level_dbfs must be between -100 and -3 dBFS, got 'loud'"),
])
def test_protocol_or_catalog_of_wrong_type_or_encoding_names_the_file(tmp_path, capsys, name, content, option,
                                                                      match):
    """Audit protocol_json_number.txt, protocol_nonutf8.txt, catalog_nonutf8.txt: a raw TypeError traceback or
    a codec message without the file; now exit 2 and one ``error:`` line naming the file (and line)."""
    path = tmp_path / name
    path.write_bytes(content)
    capsys.readouterr()
    assert run_study("--subject", "S9", "--seed", 1, "--out", tmp_path / "DATA", "--samples", "wood,firm",
                     option, path) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {path}{match}"]
    assert not (tmp_path / "DATA" / "S9").exists()
