"""`bmctl design --plant-seeds 1`: one plant is "1 plant", in the progress line and schedule.toml."""

from bmctl.cli import main

from ..conftest import ROOT

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"


def test_one_plant_is_singular(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["design", str(CARD), "--target", "s_mean_um=35", "--hours", "0.3", "--plant-seeds", "1",
                 "--plant-particles", "100", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "checking the schedule on 1 plant of 100 particles" in err, err
    assert "# plant check (1 plant of 100 particles): " in (out / "schedule.toml").read_text(encoding="utf-8")
