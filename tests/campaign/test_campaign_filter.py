"""The campaign records its particle-filter settings at ``init`` and runs its filter with them."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from bmctl import campaign as cp
from bmctl.campaign import db
from bmctl.campaign.workflow import CAMPAIGN_FILTER, Campaign
from bmctl.cli import main
from bmctl.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"


def _init(d, **kw):
    return cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100, **kw)


def test_init_records_the_campaign_filter(tmp_path):
    meta = _init(tmp_path / "c")
    assert meta["estimator"] == CAMPAIGN_FILTER
    with Campaign(tmp_path / "c") as c:
        st = c.filter_settings()
        assert st.n_particles == 100 and st.size_drift_prior_per_h == CAMPAIGN_FILTER["size_drift_prior_per_h"]
        assert c.loop.estimator.settings == st  # the filter the campaign runs


def test_init_takes_other_settings_and_refuses_unknown_ones(tmp_path):
    _init(tmp_path / "a", estimator={"roughening": 0.02})
    with Campaign(tmp_path / "a") as c:
        st = c.filter_settings()
        assert st.roughening == 0.02 and st.size_drift_prior_per_h == 0.0  # the given table replaces the campaign's
    with pytest.raises(InputError, match="^estimator: not_a_setting: unknown field$"):
        _init(tmp_path / "b", estimator={"not_a_setting": 1})
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("value", ['[1, 2]', '{"roughening": "a"}'])
def test_damaged_estimator_meta_is_one_line(tmp_path, capsys, value):
    d = tmp_path / "c"
    _init(d)
    con = sqlite3.connect(str(d / db.DB_NAME))
    with con:
        con.execute("UPDATE meta SET value = ? WHERE key = 'estimator'", (value,))
    con.close()
    capsys.readouterr()
    assert main(["campaign", "advise", str(d)]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("bmctl: error:")]
    assert len(lines) == 1 and "meta 'estimator'" in lines[0] and "Traceback" not in err


def test_campaign_learns_energy_mult_unless_told_not_to_and_the_plan_uses_it(tmp_path, capsys):
    import json

    from bmctl.campaign.workflow import TWO_MULT_FILTER

    mpc = ROOT / "controllers" / "mpc-default.toml"
    for name, flag, names in (("e", [], ("gamma_mult", "delta_mult", "energy_mult")),
                              ("n", ["--no-energy-mult"], ("gamma_mult", "delta_mult"))):
        d = tmp_path / name
        assert main(["campaign", "init", str(d), "--model", str(CARD), "--controller", str(mpc), "--target",
                     "s_mean_um=45", "--hours", "2", "--particles", "100", *flag]) == 0
        with Campaign(d) as c:
            assert c.meta["estimator"] == (TWO_MULT_FILTER if flag else CAMPAIGN_FILTER)
            assert c.loop.estimator.param_names == names
        capsys.readouterr()
        assert main(["campaign", "advise", str(d), "--json"]) == 0
        a = json.loads(capsys.readouterr().out)
        assert ("energy_mult" in a["estimate"]) == (not flag) and a["next"]["interval_h"] > 0


@pytest.mark.parametrize("flags, expected", [([], None), (["--moment-noise-at", "update"], None),
                                             (["--moment-noise-at", "sample"], "sample"),
                                             (["--no-energy-mult", "--moment-noise-at", "sample"], "sample")])
def test_init_records_when_the_filter_draws_the_moment_noise(tmp_path, capsys, flags, expected):
    from bmctl.campaign.workflow import TWO_MULT_FILTER

    d = tmp_path / "c"
    assert main(["campaign", "init", str(d), "--model", str(CARD), "--controller", str(RECIPE), "--target",
                 "d50_um=45", "--hours", "2", "--particles", "100", *flags]) == 0
    base = TWO_MULT_FILTER if "--no-energy-mult" in flags else CAMPAIGN_FILTER
    with Campaign(d) as c:
        assert c.meta["estimator"] == (base if expected is None else {**base, "moment_noise_at": expected})
        assert c.filter_settings().moment_noise_at == (expected or "update")
        assert c.loop.estimator.settings.moment_noise_at == (expected or "update")


def test_init_refuses_an_unknown_moment_noise_time(tmp_path, capsys):
    assert main(["campaign", "init", str(tmp_path / "c"), "--model", str(CARD), "--controller", str(RECIPE),
                 "--target", "d50_um=45", "--moment-noise-at", "later"]) == 2
    assert "--moment-noise-at" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()
