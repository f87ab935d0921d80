"""``analysis psychometric`` and ``analysis plan`` write their folders staged: a run stopped part-way (Ctrl-C,
SIGTERM, a full disk: any exception while it writes) leaves the earlier results exactly as they were and no
staging folder or lock beside them; a finished run replaces them whole (no old figure beside new tables).

Once: both wrote straight into ``--out``.
"""

import pytest

import analysis.cli_plan
import analysis.cli_psychometric
from analysis.__main__ import main
from tests.support.files import tree_hashes

CSV = "intensity,correct\n" + "".join(f"{x},{int(i % 4 != 0 or x > 2)}\n" for i in range(40)
                                      for x in (0.5, 1.0, 2.0, 4.0))


def _psychometric(tmp_path, *extra):
    data = tmp_path / "d.csv"
    data.write_text(CSV)
    return ["psychometric", str(data), "--alternatives", "2", "--out", str(tmp_path / "OUT"), *extra]


def _plan(tmp_path, *extra):
    return ["plan", "--dz", "0.8", "--out", str(tmp_path / "OUT"), *extra]


@pytest.mark.parametrize("command, module, writer", [
    (_psychometric, analysis.cli_psychometric, "atomic_write_text"),
    (_plan, analysis.cli_plan, "write_plan"),
])
@pytest.mark.parametrize("stop, code", [(KeyboardInterrupt, 130), (OSError(28, "No space left on device"), 2)])
def test_a_run_stopped_while_writing_keeps_the_earlier_results(tmp_path, monkeypatch, capsys, command, module,
                                                               writer, stop, code):
    out = tmp_path / "OUT"
    assert main(command(tmp_path)) == 0
    before = tree_hashes(out)
    real = getattr(module, writer)

    def stopped(*a, **k):
        real(*a, **k)          # something written into the staging folder, then the stop
        raise stop if isinstance(stop, BaseException) else stop()
    monkeypatch.setattr(module, writer, stopped)
    capsys.readouterr()
    got = main(command(tmp_path, "--force"))
    err = capsys.readouterr().err
    assert got == code and "Traceback" not in err and len(err.strip().splitlines()) == 1, (got, err)
    assert tree_hashes(out) == before                                    # the earlier results, byte for byte
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []   # no staging, no lock


def test_synthetic_data_appears_whole_or_not_at_all_and_its_size_is_bounded(tmp_path, monkeypatch, capsys):
    import analysis.cli_synthetic
    out = tmp_path / "DATA"
    assert main(["synthetic", str(out), "--subjects", "100000000"]) == 2
    assert capsys.readouterr().err == "error: --subjects must be 1..1000, got 100000000\n"
    real = analysis.cli_synthetic.write_synthetic_study

    def interrupted(folder, *a, **k):
        real(folder, *a, **k)
        raise KeyboardInterrupt
    monkeypatch.setattr(analysis.cli_synthetic, "write_synthetic_study", interrupted)
    assert main(["synthetic", str(out), "--subjects", "2"]) == 130
    assert list(tmp_path.iterdir()) == []                                # no half-written study, no debris
