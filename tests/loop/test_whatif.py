"""`bmctl whatif`: ensembles of schedules compared; bad input."""

import csv

from bmctl.cli import main

from ..conftest import ROOT, card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


def test_whatif_compares_schedules(tmp_path, capsys):
    a = tmp_path / "a.toml"
    a.write_text('name = "hot"\n[[segment]]\nhours = 2\nrpm = 400\n')
    b = tmp_path / "b.toml"
    b.write_text('name = "gentle"\n[[segment]]\nhours = 1\nrpm = 250\n[[segment]]\nhours = 1\nrpm = 0\n')
    rc = main(["whatif", LAB, str(a), str(b), "--seeds", "2", "--particles", "500", "--out", str(tmp_path / "o")])
    assert rc == 0, capsys.readouterr().err
    rows = list(csv.DictReader((tmp_path / "o" / "whatif.csv").read_text().splitlines()))
    assert [r["schedule"] for r in rows] == ["hot", "gentle"]
    hot, gentle = rows
    # physics the comparison must show: more power -> hotter and more energy
    assert float(hot["energy_kj"]) > float(gentle["energy_kj"]) > 0
    assert float(hot["peak_temperature_c"]) > float(gentle["peak_temperature_c"])
    assert float(hot["final_s_mean_um_q05"]) <= float(hot["final_s_mean_um"]) <= float(hot["final_s_mean_um_q95"])
    for png in ("whatif_moments.png", "whatif_final.png"):
        assert (tmp_path / "o" / png).read_bytes()[:4] == b"\x89PNG"


def test_whatif_bad_input(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[segment]]\nhours = 1\nrpm = 9000\n")
    rc = main(["whatif", LAB, str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "segment[0].rpm" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
    rc = main(["whatif", LAB, str(ROOT / "scenarios" / "schedule-ramp-rest.toml"), "--seeds", "0"])
    assert rc == 2 and "--seeds" in capsys.readouterr().err
