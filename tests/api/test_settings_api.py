"""A mistyped setting or target named from Python: the hint is the known key the user meant.
A key given without its unit suffix (``s_mean`` for ``s_mean_um``) is the common slip in a
project whose names carry their units; difflib alone suggested the closer-spelled ``r_mean``."""

import pytest

from bmctl.config import close_key
from bmctl.control.config import parse_target
from bmctl.errors import InputError


def test_a_key_without_its_unit_suffix_suggests_the_suffixed_key():
    assert close_key("s_mean", ["r_mean", "r_std", "s_mean_um", "s_std_um"]) == "s_mean_um"


def test_a_target_without_its_unit_names_it():
    with pytest.raises(InputError, match=r"did you mean s_mean_um\?"):
        parse_target("s_mean=30")


def test_an_ambiguous_prefix_falls_back_to_spelling():
    assert close_key("temperature", ["temperature_c", "temperature_reading"]) in ("temperature_c",
                                                                                  "temperature_reading")
    assert close_key("alpah", ["alpha", "beta"]) == "alpha"
