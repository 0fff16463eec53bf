"""A scenario's [estimator] table exposes every setting of the chosen estimator."""

import pytest

from bmctl.errors import InputError
from bmctl.scenario import load_scenario
from tests.conftest import ROOT

BASE = f'''model = "{ROOT / "models" / "alni-1to1-300rpm-lab.toml"}"
hours = 1
[scenario]
name = "x"
description = "y"
[controller]
config = "{ROOT / "controllers" / "recipe-300rpm-continuous.toml"}"
'''


def _load(tmp_path, extra):
    p = tmp_path / "s.toml"
    p.write_text(BASE + extra, encoding="utf-8")
    return load_scenario(p)


def test_pf_settings_reach_the_filter(tmp_path):
    sc = _load(tmp_path, "[estimator]\nparticles = 400\n[estimator.pf]\nroughening = 0.02\nscheme = \"residual\"\n")
    st = sc.estimator.filter_settings()
    assert (st.n_particles, st.roughening, st.scheme) == (400, 0.02, "residual")


def test_ukf_settings_reach_the_ukf(tmp_path):
    from bmctl.estimate.ukf import UKFSettings

    sc = _load(tmp_path, "[estimator]\nkind = \"ukf\"\n")
    assert isinstance(sc.estimator.filter_settings(), UKFSettings)


@pytest.mark.parametrize("extra, field", [
    ("[estimator.pf]\nroughening = \"a\"\n", "pf.roughening"),
    ("[estimator.pf]\nnot_a_setting = 1\n", "pf.not_a_setting"),
    ("[estimator.pf]\nn_particles = 10\n", "n_particles"),
])
def test_bad_filter_settings_name_the_field(tmp_path, extra, field):
    with pytest.raises(InputError, match=field.replace(".", r"\.")):
        _load(tmp_path, "[estimator]\n" + extra)
