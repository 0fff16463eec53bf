"""``benchmarks/hidden_mills.py`` on mills files written by someone else: odd batch lengths, card fields
the hidden plant does not read, values that are not numbers, another card. Each case either runs as
the file says or is refused in one line naming the file and the field, before anything is written."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bmctl.errors import InputError
from tests.conftest import load_benchmark
from tests.test_hidden_mills_mills import ROW, _file  # one mill row and the file writer

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "hidden_mills.py"


def test_the_campaign_is_given_the_mills_batch_length_unrounded(tmp_path, monkeypatch):
    """A 1 h 20 min batch (hours = 1.3333333333): ``campaign init`` gets the mill's hours, not six
    digits of it, so the operator's loop and the campaign end the batch together (a rounded batch
    ended before the loop and ``campaign decide`` failed past its end)."""
    hm = load_benchmark("hidden_mills")
    case = hm.Case("X", 1.0, 1.0, "mill.ball_count", 9, 1.3333333333, 300.0)
    given = []

    class Stop(Exception):
        pass

    def cli(args, env):
        given.append(args)
        raise Stop

    monkeypatch.setattr(hm, "cli", cli)
    with pytest.raises(Stop):
        hm.run_campaign(case, 70.0, tmp_path / "c", 100, 0, {})
    init = given[0]
    assert init[:2] == ["campaign", "init"]
    assert float(init[init.index("--hours") + 1]) == case.hours


@pytest.mark.parametrize("hours", ["1.3333333333", "2.25", "0.75", "6.0", "1.001"])
def test_batch_lengths_off_the_half_hour_grid_are_accepted(tmp_path, hours):
    cases = load_benchmark("hidden_mills").load_mills(_file(tmp_path, "[[mill]]\n" + ROW.replace("6.0", hours)))
    assert cases[0].hours == float(hours)


@pytest.mark.parametrize("text, where", [
    # a last advice interval under the 1 s the campaign logs: refused, not a failure mid-campaign
    (ROW.replace("hours = 6.0", "hours = 1.0000004"), "mill[0].hours: leaves a last interval of"),
    # card fields the hidden plant does not read: the mill would only seem to differ
    (ROW.replace('"mill.ball_count"', '"process.hours"').replace("value = 9", "value = 2.0"),
     "mill[0].field: the card's recipe does not change the hidden plant"),
    (ROW.replace('"mill.ball_count"', '"simulation.particles"').replace("value = 9", "value = 500"),
     "mill[0].field: the hidden plant's particles are --particles"),
    (ROW.replace('"mill.ball_count"', '"validity.calibrated_temperature_max_C"').replace("value = 9", "value = 90.0"),
     "mill[0].field: where the card holds does not change the hidden plant"),
    # the multipliers set gamma and delta: a value here would silently replace gamma_mult
    (ROW.replace('"mill.ball_count"', '"stochastic.gamma_per_um2"').replace("value = 9", "value = 2e-4"),
     "mill[0].field: set through gamma_mult"),
    (ROW.replace('"mill.ball_count"', '"stochastic.delta_per_um2"').replace("value = 9", "value = 9e-4"),
     "mill[0].field: set through delta_mult"),
    # a field the card leaves unset
    (ROW.replace('"mill.ball_count"', '"validity.rpm_max"').replace("value = 9", "value = 500.0"),
     "mill[0].field: not set on the card"),
    # not a number: one message naming value, not the integer branch of its type
    (ROW.replace('"mill.ball_count"', '"thermal.ambient_C"').replace("value = 9", "value = nan"),
     "mill[0].value: must be a finite number (got nan)"),
    (ROW.replace('"mill.ball_count"', '"thermal.ambient_C"').replace("value = 9", "value = inf"),
     "mill[0].value: must be a finite number (got inf)"),
    (ROW.replace("value = 9", 'value = "9"'), "mill[0].value: must be a finite number"),
    (ROW.replace("value = 9", "value = true"), "mill[0].value: must be a finite number"),
])
def test_a_mill_that_would_not_be_what_it_says_is_refused_in_one_line(tmp_path, text, where):
    p = _file(tmp_path, "[[mill]]\n" + text)
    with pytest.raises(InputError) as e:
        load_benchmark("hidden_mills").load_mills(p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and where in msg and "\n" not in msg and ".int" not in msg, msg


def test_denser_balls_are_heavier_balls():
    """``mill.ball_density_kg_m3``: one ball's mass follows its density, as it follows its size for
    ``mill.ball_diameter_m`` (else the hidden card contradicts itself and only the contact radius changes)."""
    hm = load_benchmark("hidden_mills")
    from bmctl.config import load_card

    lab = load_card(hm.CARD)
    card = hm.hidden_card(hm.Case("X", 1.0, 1.0, "mill.ball_density_kg_m3", 2 * lab.mill.ball_density_kg_m3,
                                  6.0, 300.0))
    assert card.material.impactor_mass_kg == pytest.approx(2 * lab.material.impactor_mass_kg)
    assert card.mill.ball_density_kg_m3 == pytest.approx(2 * lab.mill.ball_density_kg_m3)


def test_the_printed_table_points_at_the_results_file_the_run_writes():
    hm = load_benchmark("hidden_mills")
    keys = ("target_s_mean_um", "error_pct", "peak_c", "idle_needed_h", "longest_idle_needed_h", "plain_error_pct")
    row = {"case": "X", "gamma_mult": 1.2, "delta_mult": 0.8, "field": "mill.ball_count", "value": 9, "hours": 6.0,
           "plain_schedule": "300 rpm continuous", **dict.fromkeys(keys, 1.0)}
    summary = dict.fromkeys(("median_error_pct", "worst_error_pct", "max_over_ceiling_c", "longest_idle_needed_h",
                             "plain_median_error_pct", "plain_worst_error_pct"), 1.0) | {"campaign_beats_plain": 1}
    text = hm.table([row], summary, "hidden_mills_mine")
    assert "<!--r:hidden_mills_mine.json:cases.0.error_pct-->" in text
    assert "<!--r:hidden_mills_mine.json:summary.worst_error_pct-->" in text
    assert "hidden_mills.json" not in text
    assert "<!--r:hidden_mills.json:cases.0.error_pct-->" in hm.table([row], summary)  # the default file's


def test_a_card_whose_own_sweep_runs_over_the_ceiling_is_refused_before_anything_is_written(tmp_path, monkeypatch,
                                                                                           capsys):
    """The hidden plant has a target, but every plain schedule on the card's plant runs over the
    ceiling (a card of a hot mill): one line, exit 2, no folder made (not a traceback after the
    campaign folders were claimed)."""
    hm = load_benchmark("hidden_mills")
    p = _file(tmp_path, "[[mill]]\n" + ROW.replace("hours = 6.0", "hours = 0.5"))
    calls = []

    def sweep(card, hours, particles, seed):  # the hidden plant first (cool), then the card's (hot)
        calls.append(card)
        peak = 40.0 if len(calls) == 1 else 95.0
        return [{"name": name, "s_mean_um": 40.0, "peak_c": peak, "segments": segs}
                for name, segs in hm.plain_schedules(hours)]

    monkeypatch.setattr(hm, "sweep", sweep)
    out = tmp_path / "out"
    monkeypatch.setattr(sys, "argv", ["hidden_mills.py", "--mills", str(p), "--no-results", "--out", str(out)])
    with pytest.raises(SystemExit) as e:
        hm.main()
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no schedule of the sweep stays under the 80 °C ceiling on the card's plant" in err[0]
    assert not out.exists()


def test_a_card_slower_than_the_sweep_is_named_as_the_card(tmp_path):
    """A card whose mill tops out under the sweep's 500 rpm: the line names the card and its
    mill.rpm_max (not the mills file, nor 'give it on the card': it is on the card)."""
    card = tmp_path / "slow.toml"
    card.write_text((ROOT / "models" / "alni-1to1-300rpm-lab.toml").read_text(encoding="utf-8").replace("rpm_max = 600",
                                                                                       "rpm_max = 450"), encoding="utf-8")
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, str(SCRIPT), "--card", str(card), "--no-results", "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr[-600:]
    assert f"--card {card}: mill.rpm_max:" in lines[0] and "450" in lines[0]
    assert not out.exists()
