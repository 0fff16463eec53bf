"""docs/own-mill.md: the worked example card loads, derives what the page says, shows and simulates."""

import csv
import math
import re

import pytest

from bmctl.cli import main
from bmctl.config import load_card

from tests.conftest import ROOT

DOC = ROOT / "docs" / "own-mill.md"


def doc_card(tmp_path):
    blocks = re.findall(r"```toml\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    assert len(blocks) == 1, "docs/own-mill.md should hold exactly one TOML card"
    p = tmp_path / "my-mill.toml"
    p.write_text(blocks[0], encoding="utf-8")
    return p


def test_doc_card_derives_masses_and_law_of_mixtures(tmp_path):
    card = load_card(doc_card(tmp_path))
    ball = 7900 * math.pi / 6 * 0.012**3  # steel, 12 mm: rho pi d^3 / 6
    assert card.material.impactor_mass_kg == pytest.approx(ball, rel=1e-12)
    assert card.mill.ball_to_powder_ratio == pytest.approx(6 * ball / 0.0027, rel=1e-12)
    # molar law of mixtures, Al:Ni = 1:2 (Callister: E 69 / 207 GPa, sigma 35 / 138 MPa)
    assert card.material.elastic_modulus_Pa == pytest.approx((69e9 + 2 * 207e9) / 3, rel=1e-12)
    assert card.material.yield_stress_Pa == pytest.approx((35e6 + 2 * 138e6) / 3, rel=1e-12)
    m_al, m_ni = 26.982e-3, 58.693e-3
    rho = (m_al + 2 * m_ni) / (m_al / 2700 + 2 * m_ni / 8900)
    assert card.material.powder_density_kg_m3 == pytest.approx(rho, rel=1e-12)
    assert card.mill.ball_density_kg_m3 == 7900 and card.mill.ball_modulus_Pa == 200e9


@pytest.mark.slow
def test_doc_card_shows_and_simulates(tmp_path, capsys):
    p = doc_card(tmp_path)
    assert main(["card", "show", str(p)]) == 0
    out = capsys.readouterr().out
    assert "ball mass          7.148 g" in out and "660.3 °C (melting point of Al)" in out
    shown = re.search(r"\$ bmctl card show my-mill.toml\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S).group(1)
    out = out.replace(str(tmp_path) + "/", "")  # the page runs it where the card is
    assert shown == "".join(ln.rstrip() + "\n" for ln in out.splitlines()), "the page's card show output is stale"
    rc = main(["simulate", str(p), "--hours", "1", "--particles", "500", "--out", str(tmp_path / "o"), "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    rows = list(csv.DictReader((tmp_path / "o" / "moments.csv").read_text(encoding="utf-8").splitlines()))
    assert [float(r["t_h"]) for r in rows] == [0.0, 1.0]
    assert 25.0 < float(rows[-1]["temperature_c"]) < 660.3


def test_doc_card_with_a_contradictory_ball_mass_is_refused(tmp_path, capsys):
    p = doc_card(tmp_path)
    # the paper's 4.14 g (a 10 mm ball) stated beside 12 mm balls: a 12 mm steel ball is 7.15 g
    text = re.sub(r"^\[material\].*$", lambda m: m.group(0) + "\nimpactor_mass_kg = 4.14e-3", p.read_text(encoding="utf-8"),
                  count=1, flags=re.M)
    assert "impactor_mass_kg = 4.14e-3" in text
    p.write_text(text, encoding="utf-8")
    assert main(["card", "show", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "material.impactor_mass_kg" in err[0] and "7.148e-03" not in err[0]
    assert "0.00715" in err[0] or "0.007148" in err[0]
