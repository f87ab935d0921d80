"""Issue 38, item 11: a catalog whose HFAM ``library`` names some other file (``"../../etc/passwd"``) is refused
with an error that names the path and what kind of file it is, never the file's content."""

import pytest

from study.__main__ import main as study_main

SECRET = b"hunter2-SECRET-0123456789\n"


@pytest.mark.parametrize("content, kind", [(SECRET, "a text file"), (b"\x01\x02" + SECRET, "another binary format")])
def test_a_library_path_to_another_file_never_echoes_its_content(tmp_path, capsys, content, kind):
    (tmp_path / "private").mkdir()
    secret = tmp_path / "private" / "passwd"
    secret.write_bytes(content)
    (tmp_path / "cat").mkdir()
    catalog = tmp_path / "cat" / "catalog.toml"
    catalog.write_text('include_default = true\n[[sample]]\nname = "evil"\nkind = "virtual"\nstiffness_N_m = 1000.0\n'
                       'transient = "hfam"\nlibrary = "../private/passwd"\n')
    code = study_main(["run", "--device", "sim", "--participant", "simulated", "--subject", "S1", "--quiet",
                       "--out", str(tmp_path / "DATA"), "--catalog", str(catalog), "--samples", "wood,evil"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("error: ") and "passwd: HFAM library is not an .npz (zip) archive" in err, err
    assert f"({kind}, without the zip signature)" in err
    for k in range(4, len(SECRET)):        # not even a few bytes of it
        assert SECRET[k - 4:k].decode() not in err.split("passwd", 1)[1], err
    assert not (tmp_path / "DATA" / "S1").exists()
