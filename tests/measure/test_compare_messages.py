"""`bmctl compare`: what the printed lines say at the edges (p-value bounds, an image given)."""

from __future__ import annotations

from bmctl.cli import main
from bmctl.measure.tables import ParticleTable, write_table

from ..conftest import card_path

CARD = str(card_path("alni-1to1-300rpm-lab"))


def test_anderson_darling_floor_is_printed_as_a_bound(capsys, tmp_path):
    """scipy floors the AD p-value at 0.001; the line must not claim p = 0.001."""
    t = tmp_path / "far.csv"
    write_table(t, ParticleTable.from_size_aspect([400.0 + i for i in range(50)], [0.3 + 0.002 * i for i in range(50)]))
    rc = main(["compare", str(t), "--model", CARD, "--at-h", "0", "--particles", "200", "--out", str(tmp_path / "o")])
    text, err = capsys.readouterr()
    assert rc == 0, err
    lines = [ln for ln in text.splitlines() if "Anderson-Darling" in ln]
    assert len(lines) == 2 and all("p ≤ 0.001" in ln and "p = 0.001" not in ln for ln in lines), text


def test_micrograph_given_to_compare_is_refused_with_a_hint(capsys, tmp_path):
    img = tmp_path / "m.tif"
    img.write_bytes(b"II*\x00\xff\xfe\x00\x01" * 8)
    rc = main(["compare", str(img), "--model", CARD, "--at-h", "1", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert "micrograph" in err and "bmctl measure" in err and str(img) in err
    assert not (tmp_path / "o").exists()
