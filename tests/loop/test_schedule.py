"""The one schedule type: TOML, card recipes, plan inputs, pieces between two times."""

import pytest

from bmctl.config import load_card
from bmctl.errors import InputError
from bmctl.schedule import Schedule

from ..conftest import card_path


def test_toml_with_milling_share(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('name = "x"\n[[segment]]\nhours = 2\nrpm = 300\nmilling = 0.25\n[[segment]]\nhours = 1\nrpm = 0\n', encoding="utf-8")
    s = Schedule.load(p)
    assert s.name == "x" and s.hours == 3.0
    assert s.pairs() == [(0.5, 300.0), (1.5, 0.0), (1.0, 0.0)]
    assert s.grid(0.5) == [(300.0, 0.25)] * 4 + [(0.0, 1.0)] * 2


@pytest.mark.parametrize("text,field", [("[[segment]]\nhours = -1\nrpm = 300\n", "hours"),
                                        ("[[segment]]\nhours = 1\nrpm = 300\nmilling = 2\n", "milling"),
                                        ("[[segment]]\nhours = 1\nrpm = 300\nspeed = 1\n", "speed")])
def test_bad_schedule_one_line(tmp_path, text, field):
    p = tmp_path / "s.toml"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=field):
        Schedule.load(p)


def test_card_recipe_cycles():
    card = load_card(card_path("alni-1to1-400rpm-fan"))
    s = Schedule.from_card(card, hours=1.0)
    p = card.process
    if p.mode == "interrupted":  # mill_min of milling, rest_min of rest, cut at the end
        assert s.pairs()[0] == (pytest.approx(p.mill_min / 60), p.rpm) and s.pairs()[1][1] == 0.0
    assert s.hours == pytest.approx(1.0)


def test_inputs_between_rests_after_the_end():
    s = Schedule.from_pairs([(1.0, 300.0), (1.0, 0.0)])
    assert s.inputs_between(0.5, 3.0) == [(300.0, 1.0, 0.5), (0.0, 0.0, 1.0), (0.0, 0.0, 1.0)]


def test_from_inputs_merges_equal_neighbours():
    s = Schedule.from_inputs([[300.0, 0.5], [300.0, 1.0], [0.0, 0.0], [350.0, 1.0]], 0.5)
    assert s.pairs() == [(0.25, 300.0), (0.25, 0.0), (0.5, 300.0), (0.5, 0.0), (0.5, 350.0)]
    assert Schedule.load  # the TOML round trip
    assert Schedule.from_pairs(s.pairs()).toml().count("[[segment]]") == 5


def test_toml_comments_give_the_minutes_written():
    """Intervals of 0.33 h are 19.8 min: the comment said `# 20 min`."""
    text = Schedule.from_inputs([[300.0, 1.0], [0.0, 0.0], [300.0, 1.0]], 0.33).toml()
    assert "# 19.8 min" in text and "# 20 min" not in text
    assert "# 30 min" in Schedule.from_pairs([(0.5, 300.0)]).toml()


def _one_segment(tmp_path, hours, milling):
    p = tmp_path / "s.toml"
    p.write_text(f"[[segment]]\nhours = {hours}\nrpm = 300\nmilling = {milling}\n", encoding="utf-8")
    return p


@pytest.mark.parametrize("milling,phase", [(0.0001, "mills 0.18 s"), (0.99999, "rests 0.018 s")])
def test_a_share_leaving_a_phase_under_six_seconds_is_refused(tmp_path, milling, phase):
    """A share of 0.0001 of 0.5 h mills 0.18 s (0.99999 rests 0.018 s): under the 6 s a mill or rest
    phase lasts at least (bmctl.limits.PHASE_MIN_MINUTES), and was run."""
    p = _one_segment(tmp_path, 0.5, milling)
    with pytest.raises(InputError) as e:
        Schedule.load(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: segment[0].milling: {phase}") and "6 s" in msg and "\n" not in msg, msg


@pytest.mark.parametrize("hours,milling", [(0.5, 0.0), (0.5, 1.0), (0.5, 0.5), (12 / 3600, 0.5)])
def test_shares_of_zero_one_or_six_second_phases_are_kept(tmp_path, hours, milling):
    s = Schedule.load(_one_segment(tmp_path, hours, milling))
    assert s.segments[0].milling == milling
