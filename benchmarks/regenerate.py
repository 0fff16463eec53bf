"""Regenerate the results files that README.md and docs/ quote, and refresh the docs' marked numbers.

Every study or benchmark whose numbers a doc quotes is registered below with the command that
writes its ``results/<name>.json`` (``bmctl.results.write_results``). Slow: the whole set takes
hours on two cores; it is not part of the test suite.

    python benchmarks/regenerate.py --list              # registered files, their commands and costs
    python benchmarks/regenerate.py --only NAME [NAME]  # re-run some studies (shell patterns too:
                                                        # --only 'hidden_mills*')
    python benchmarks/regenerate.py --only 'hidden_mills*' --jobs 2
                                                        # two studies at a time, each one's output in
                                                        # out/regenerate/NAME.log (timings still alone, last)
    python benchmarks/regenerate.py                     # re-run every study (timings last; not the
                                                        # manual ones, which need an older checkout)
    python benchmarks/regenerate.py --docs              # rewrite the numbers inside the docs' markers
                                                        # from the results files (same displayed decimals)

``--docs`` does not run anything: it puts each file's current value between the
``<!--r:FILE:KEY-->`` and ``<!--/r-->`` markers of README.md and docs/*.md, keeping the number of
decimals shown (a placeholder such as ``?`` gets three significant digits). The prose around a
number is not rewritten: read the diff.
"""

from __future__ import annotations

import argparse
import fnmatch
import math
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


@dataclass(frozen=True)
class Study:
    name: str  # results file stem
    command: str  # run from the repository root; writes results/<name>.json
    minutes: float  # rough cost on one idle core
    timing: bool = False  # wall-clock numbers: run last, on a quiet machine
    manual: bool = False  # run only when named with --only (it needs an older checkout at /tmp/base)


#: one entry per results file; each file's ``command`` field is this string (tests/test_results_commands.py
#: checks both, and that the command still parses with its script's current arguments)
REGISTRY: tuple[Study, ...] = (
    Study("model_facts", "python benchmarks/model_facts.py", 3),
    Study("fidelity_table", "python benchmarks/fidelity_table.py --particles 20000 --seed 2024", 2),
    Study("fidelity_table_no_equiaxing",
          "python benchmarks/fidelity_table.py --particles 20000 --seed 2024 --no-equiaxing", 2),
    Study("dvalues_accuracy", "python benchmarks/dvalues_accuracy.py --schedules 4 --particles 3000 --seeds 2", 4),
    Study("verify", "python benchmarks/verify_results.py", 10),
    Study("calibration_check", "python benchmarks/calibration_check.py", 10),
    Study("calibrate_accuracy", "python benchmarks/calibrate_accuracy.py main --workers 2 --seed 1", 2),
    Study("calibrate_coverage", "python benchmarks/calibrate_accuracy.py coverage --first 1 --n 20 --workers 2", 10),
    Study("calibrate_four", "python benchmarks/calibrate_accuracy.py four --workers 2 --seed 1", 10),
    Study("calibrate_bias", "python benchmarks/calibrate_bias.py --workers 2", 30),
    Study("pf_study", "python benchmarks/pf_study.py", 10),
    Study("pf_study_laws", "python benchmarks/pf_study.py --laws", 2),
    Study("pf_study_ablation", "python benchmarks/pf_study.py --ablation --seeds 10", 8),
    Study("estimator_study", "python benchmarks/estimator_study.py --seeds 10", 15),
    Study("design_reach", "python benchmarks/design_reach.py", 5),
    Study("hidden_mills", "python benchmarks/hidden_mills.py", 8),
    Study("control_study", "python benchmarks/control_study.py --seeds 20", 45),
    Study("hidden_mills_noise", "python benchmarks/hidden_mills.py --noise", 1),
    Study("hidden_mills_seed1_all", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 "
          "--results-name hidden_mills_seed1_all", 8),
    Study("hidden_mills_seed2_all", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 2 "
          "--results-name hidden_mills_seed2_all", 8),
    Study("hidden_mills_heldout", "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 0 "
          "--results-name hidden_mills_heldout", 6),
    Study("hidden_mills_heldout_seed1", "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 1 "
          "--results-name hidden_mills_heldout_seed1", 6),
    Study("hidden_mills_unseen", "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml "
          "--cases M,N,O,P,Q,R,S --seed 0 --results-name hidden_mills_unseen", 8),
    Study("hidden_mills_unseen_seed1", "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml "
          "--cases M,N,O,P,Q,R,S --seed 1 --results-name hidden_mills_unseen_seed1", 8),
    Study("hidden_mills_out_of_reach", "python benchmarks/hidden_mills.py --mills benchmarks/mills-out-of-reach.toml "
          "--cases T1,T2,T3 --seed 0 --results-name hidden_mills_out_of_reach", 3),
    Study("hidden_mills_onrequest_unseen", "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml "
          "--cases M,N,O,P,Q,R,S --seed 0 --sample-on-request --results-name hidden_mills_onrequest_unseen", 8),
    Study("hidden_mills_fields", "python benchmarks/hidden_mills.py --mills benchmarks/mills-fields.toml "
          "--cases V1,V2,V3,V4,V5,V6 --seed 0 --results-name hidden_mills_fields", 7),
    Study("hidden_mills_fields_seed1", "python benchmarks/hidden_mills.py --mills benchmarks/mills-fields.toml "
          "--cases V1,V2,V3,V4,V5,V6 --seed 1 --results-name hidden_mills_fields_seed1", 7),
    Study("hidden_mills_halfhourly_seed1_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 "
          "--sample-every-h 0.5 --results-name hidden_mills_halfhourly_seed1_all", 9),
    Study("hidden_mills_halfhourly_seed2_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 2 "
          "--sample-every-h 0.5 --results-name hidden_mills_halfhourly_seed2_all", 9),
    Study("hidden_mills_halfhourly_unseen",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,N,O,P,Q,R,S --seed 0 "
          "--sample-every-h 0.5 --results-name hidden_mills_halfhourly_unseen", 9),
    Study("hidden_mills_halfhourly_unseen_seed1",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,N,O,P,Q,R,S --seed 1 "
          "--sample-every-h 0.5 --results-name hidden_mills_halfhourly_unseen_seed1", 9),
    Study("hidden_mills_narrowpool",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 0 "
          "--controller benchmarks/mpc-narrow-pool.toml --results-name hidden_mills_narrowpool", 8),
    Study("hidden_mills_narrowpool_seed1_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 "
          "--controller benchmarks/mpc-narrow-pool.toml --results-name hidden_mills_narrowpool_seed1_all", 8),
    Study("hidden_mills_narrowpool_seed2_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 2 "
          "--controller benchmarks/mpc-narrow-pool.toml --results-name hidden_mills_narrowpool_seed2_all", 8),
    Study("hidden_mills_narrowpool_heldout",
          "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 0 "
          "--controller benchmarks/mpc-narrow-pool.toml --results-name hidden_mills_narrowpool_heldout", 6),
    Study("hidden_mills_narrowpool_heldout_seed1",
          "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 1 "
          "--controller benchmarks/mpc-narrow-pool.toml --results-name hidden_mills_narrowpool_heldout_seed1", 6),
    Study("hidden_mills_narrowpool_unseen",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,N,O,P,Q,R,S --seed 0 "
          "--controller benchmarks/mpc-narrow-pool.toml --results-name hidden_mills_narrowpool_unseen", 8),
    Study("hidden_mills_narrowpool_unseen_seed1",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,N,O,P,Q,R,S --seed 1 "
          "--controller benchmarks/mpc-narrow-pool.toml --results-name hidden_mills_narrowpool_unseen_seed1", 8),
    Study("hidden_mills_onset8",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 0 "
          "--controller benchmarks/mpc-onset8.toml --results-name hidden_mills_onset8", 8),
    Study("hidden_mills_onset8_seed1_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 "
          "--controller benchmarks/mpc-onset8.toml --results-name hidden_mills_onset8_seed1_all", 8),
    Study("hidden_mills_onset8_seed2_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 2 "
          "--controller benchmarks/mpc-onset8.toml --results-name hidden_mills_onset8_seed2_all", 8),
    Study("hidden_mills_onset8_heldout",
          "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 0 "
          "--controller benchmarks/mpc-onset8.toml --results-name hidden_mills_onset8_heldout", 6),
    Study("hidden_mills_onset8_heldout_seed1",
          "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 1 "
          "--controller benchmarks/mpc-onset8.toml --results-name hidden_mills_onset8_heldout_seed1", 6),
    Study("hidden_mills_lqr",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 0 "
          "--controller controllers/lqr-baseline.toml --results-name hidden_mills_lqr", 12),
    Study("hidden_mills_lqr_unseen",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,N,O,P,Q,R,S --seed 0 "
          "--controller controllers/lqr-baseline.toml --results-name hidden_mills_lqr_unseen", 12),
    Study("hidden_mills_scenario",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 0 "
          "--controller controllers/mpc-scenario.toml --results-name hidden_mills_scenario", 18),
    Study("hidden_mills_halfhourly_nudge_seed1_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 --controller benchmarks/mpc-nudge.toml "
          "--sample-every-h 0.5 --results-name hidden_mills_halfhourly_nudge_seed1_all", 10),
    Study("hidden_mills_halfhourly_nudge_seed2_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 2 --controller benchmarks/mpc-nudge.toml "
          "--sample-every-h 0.5 --results-name hidden_mills_halfhourly_nudge_seed2_all", 10),
    Study("hidden_mills_halfhourly_nudge_unseen",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,N,O,P,Q,R,S --seed 0 "
          "--controller benchmarks/mpc-nudge.toml "
          "--sample-every-h 0.5 --results-name hidden_mills_halfhourly_nudge_unseen", 10),
    Study("hidden_mills_halfhourly_nudge_unseen_seed1",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,N,O,P,Q,R,S --seed 1 "
          "--controller benchmarks/mpc-nudge.toml "
          "--sample-every-h 0.5 --results-name hidden_mills_halfhourly_nudge_unseen_seed1", 10),
    Study("hidden_mills_nudge",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 0 "
          "--controller benchmarks/mpc-nudge.toml --results-name hidden_mills_nudge", 8),
    Study("hidden_mills_nudge_seed1_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 "
          "--controller benchmarks/mpc-nudge.toml --results-name hidden_mills_nudge_seed1_all", 8),
    Study("hidden_mills_nudge_seed2_all",
          "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 2 "
          "--controller benchmarks/mpc-nudge.toml --results-name hidden_mills_nudge_seed2_all", 8),
    Study("hidden_mills_nudge_heldout",
          "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 0 "
          "--controller benchmarks/mpc-nudge.toml --results-name hidden_mills_nudge_heldout", 6),
    Study("hidden_mills_nudge_heldout_seed1",
          "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 1 "
          "--controller benchmarks/mpc-nudge.toml --results-name hidden_mills_nudge_heldout_seed1", 6),
    Study("hidden_mills_nudge_unseen",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,N,O,P,Q,R,S --seed 0 "
          "--controller benchmarks/mpc-nudge.toml --results-name hidden_mills_nudge_unseen", 8),
    Study("hidden_mills_nudge_unseen_seed1",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,N,O,P,Q,R,S --seed 1 "
          "--controller benchmarks/mpc-nudge.toml --results-name hidden_mills_nudge_unseen_seed1", 8),
    Study("hidden_mills_twomult", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 0 "
          "--no-energy-mult --results-name hidden_mills_twomult", 8),
    Study("hidden_mills_twomult_seed1_all", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 "
          "--no-energy-mult --results-name hidden_mills_twomult_seed1_all", 8),
    Study("hidden_mills_twomult_seed2_all", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 2 "
          "--no-energy-mult --results-name hidden_mills_twomult_seed2_all", 8),
    Study("hidden_mills_twomult_heldout", "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 0 "
          "--no-energy-mult --results-name hidden_mills_twomult_heldout", 6),
    Study("hidden_mills_twomult_heldout_seed1", "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 1 "
          "--no-energy-mult --results-name hidden_mills_twomult_heldout_seed1", 6),
    Study("hidden_mills_noise_samples1000", "python benchmarks/hidden_mills.py --noise --sample-particles 1000 "
          "--results-name hidden_mills_noise_samples1000", 0.2),
    Study("hidden_mills_samples1000", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 0 "
          "--sample-particles 1000 --results-name hidden_mills_samples1000", 10),
    Study("hidden_mills_samples1000_seed1_all", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 "
          "--sample-particles 1000 --results-name hidden_mills_samples1000_seed1_all", 10),
    Study("hidden_mills_samples1000_seed2_all", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 2 "
          "--sample-particles 1000 --results-name hidden_mills_samples1000_seed2_all", 10),
    Study("hidden_mills_samples1000_heldout", "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 0 "
          "--sample-particles 1000 --results-name hidden_mills_samples1000_heldout", 7),
    Study("hidden_mills_samples1000_heldout_seed1", "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 1 "
          "--sample-particles 1000 --results-name hidden_mills_samples1000_heldout_seed1", 7),
    Study("hidden_mills_onrequest", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 0 "
          "--sample-on-request --results-name hidden_mills_onrequest", 9),
    Study("hidden_mills_onrequest_seed1_all", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 "
          "--sample-on-request --results-name hidden_mills_onrequest_seed1_all", 9),
    Study("hidden_mills_onrequest_seed2_all", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 2 "
          "--sample-on-request --results-name hidden_mills_onrequest_seed2_all", 9),
    Study("hidden_mills_onrequest_heldout", "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 0 "
          "--sample-on-request --results-name hidden_mills_onrequest_heldout", 7),
    Study("hidden_mills_onrequest_heldout_seed1", "python benchmarks/hidden_mills.py --cases H,I,J,K,L --seed 1 "
          "--sample-on-request --results-name hidden_mills_onrequest_heldout_seed1", 7),
    Study("hidden_mills_feedvial", "python benchmarks/hidden_mills.py --mills benchmarks/mills-feed-vial.toml "
          "--cases W1,W2,W3,W4,W5,W6 --seed 0 --results-name hidden_mills_feedvial", 8),
    Study("hidden_mills_feedvial_seed1", "python benchmarks/hidden_mills.py --mills benchmarks/mills-feed-vial.toml "
          "--cases W1,W2,W3,W4,W5,W6 --seed 1 --results-name hidden_mills_feedvial_seed1", 8),
    Study("hidden_mills_feedvial_feed", "python benchmarks/hidden_mills.py --mills benchmarks/mills-feed-vial.toml "
          "--cases W1,W2,W3,W4,W5,W6 --seed 0 --sample-feed --results-name hidden_mills_feedvial_feed", 8),
    Study("hidden_mills_feedvial_feed_seed1",
          "python benchmarks/hidden_mills.py --mills benchmarks/mills-feed-vial.toml "
          "--cases W1,W2,W3,W4,W5,W6 --seed 1 --sample-feed --results-name hidden_mills_feedvial_feed_seed1", 8),
    Study("hidden_mills_1to3", "python benchmarks/hidden_mills.py --card models/alni-1to3-300rpm-hadjiafxenti.toml "
          "--mills benchmarks/mills-1to3.toml --cases Y1,Y2,Y3,Y4,Y5,Y6 --seed 0 --results-name hidden_mills_1to3", 8),
    Study("hidden_mills_1to3_seed1", "python benchmarks/hidden_mills.py --card models/alni-1to3-300rpm-hadjiafxenti.toml "
          "--mills benchmarks/mills-1to3.toml --cases Y1,Y2,Y3,Y4,Y5,Y6 --seed 1 --results-name hidden_mills_1to3_seed1",
          8),
    Study("hidden_mills_atsample_seed1_all", "python benchmarks/hidden_mills.py --cases A,B,C,D,E,F,G --seed 1 "
          "--moment-noise-at sample --results-name hidden_mills_atsample_seed1_all", 17),
    Study("hidden_mills_atsample_unseen", "python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml "
          "--cases M,N,O,P,Q,R,S --seed 0 --moment-noise-at sample --results-name hidden_mills_atsample_unseen", 17),
    Study("hidden_mills_atsample_fields_seed1", "python benchmarks/hidden_mills.py --mills benchmarks/mills-fields.toml "
          "--cases V1,V2,V3,V4,V5,V6 --seed 1 --moment-noise-at sample --results-name hidden_mills_atsample_fields_seed1",
          11),
    # reads the default, the 1000-particle and the on-request hidden-mill files above
    Study("hidden_mills_floor", "python benchmarks/hidden_mills_floor.py", 0.1),
    Study("estimate_replay", "python benchmarks/estimate_replay.py", 20),
    Study("rest_noise", "python benchmarks/rest_noise.py", 6),
    Study("feed_sample", "python benchmarks/feed_sample.py", 2),
    Study("model_form", "python benchmarks/model_form.py", 3),
    Study("moments_shipped", "python benchmarks/moments_table.py", 0.1),
    Study("moments_confirm", "python benchmarks/moments_confirm.py --shipped", 3),
    Study("moments_confirm_stream5", "python benchmarks/moments_confirm.py --shipped --stream 5 --seeds 31 32 33", 3),
    Study("moments_numerics", "python benchmarks/moments_numerics.py", 0.5),
    Study("gamma_delta_response", "python benchmarks/gamma_delta_response.py", 0.5),
    Study("moments_plant_shape", "python benchmarks/moments_plant_shape.py", 0.3),
    Study("calibrated_card", "python benchmarks/calibrated_card_check.py", 3),
    Study("measure_emps", "python benchmarks/measure_emps.py", 1),
    Study("measure_perimeter", "python benchmarks/measure_accuracy.py perimeter", 0.2),
    Study("measure_synthetic", "python benchmarks/measure_accuracy.py synthetic", 2),
    Study("measure_real", "python benchmarks/measure_accuracy.py real", 3),
    Study("measure_sensitivity", "python benchmarks/measure_accuracy.py sensitivity", 5),
    Study("fuzz", "nice -n 5 python benchmarks/fuzz.py --cases 2250", 6),
    # this script on the segmentation of 41dff7f (before automatic polarity), in a git worktree at /tmp/base that
    # must not exist yet: one at a time with --only, `git worktree remove --force /tmp/base` after each
    Study("measure_emps_baseline_bright",
          "git worktree add --detach /tmp/base 41dff7f && cp benchmarks/measure_emps.py /tmp/base/benchmarks/ && "
          "cd /tmp/base && BMCTL_RESULTS_DIR=$OLDPWD/results python benchmarks/measure_emps.py --polarity bright "
          "--name measure_emps_baseline_bright", 1, manual=True),
    Study("measure_emps_baseline_best",
          "git worktree add --detach /tmp/base 41dff7f && cp benchmarks/measure_emps.py /tmp/base/benchmarks/ && "
          "cd /tmp/base && BMCTL_RESULTS_DIR=$OLDPWD/results python benchmarks/measure_emps.py --polarity best "
          "--name measure_emps_baseline_best", 2, manual=True),
    # timings: re-measured at the end on a quiet machine (each file records the load)
    Study("bench_identify", "python benchmarks/bench_identify.py --repeat 2", 6, timing=True),
    Study("bench_moments", "python benchmarks/bench_moments.py", 0.5, timing=True),
    Study("calibrate_scaling", "python benchmarks/calibrate_accuracy.py scaling --calibration", 3, timing=True),
    Study("bench_estimate", "python benchmarks/bench_estimate.py", 1, timing=True),
    Study("bench_plant", "python benchmarks/bench_plant.py", 1, timing=True),
    Study("bench_ensemble", "python benchmarks/bench_ensemble.py", 1, timing=True),
    Study("campaign_advise", "python benchmarks/campaign_advise.py", 3, timing=True),
    Study("bench_control", "python benchmarks/bench_control.py", 1, timing=True),
    Study("bench_control_compiled", "python benchmarks/bench_control.py --compiled", 9, timing=True),
    Study("bench_control_nlp", "python benchmarks/bench_control.py --nlp", 1, timing=True),
    Study("bench_fresh", "python benchmarks/bench_fresh.py", 5, timing=True),
    Study("test_suite", "python benchmarks/test_suite.py", 20, timing=True),
    # timed beside 41dff7f in a git worktree at /tmp/base that must not exist yet (as the baselines above)
    Study("bench_measure", "git worktree add --detach /tmp/base 41dff7f && python benchmarks/bench_measure.py "
          "--against /tmp/base", 2, timing=True, manual=True),
)

MARKER = re.compile(r"(<!--r:([^:>\s]+):([^>\n]+?)-->)(.*?)(<!--/r-->)", re.S)


def docs() -> list[Path]:
    return sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])


SHOWN = re.compile(r"([+\-−]?)(\d[\d,]*)(?:\.(\d+))?(?:(e|E|·10|×10)\^?([+\-−⁻⁺]?[\d⁰¹²³⁴⁵⁶⁷⁸⁹]+))?([kM]?)")
SUP = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")


def format_like(value, shown: str) -> str:
    """``value`` displayed as ``shown`` is: decimals, thousands separator, k/M suffix, scientific
    style (``4.5e-3``, ``2.3·10⁻⁴``, ``2×10⁻⁴``) and minus sign; a placeholder gets 3 significant digits."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool) or not math.isfinite(value):
        return str(value)
    m = SHOWN.fullmatch(shown.strip())
    if not m:
        if value == 0:
            return "0"
        dec = max(0, 2 - int(math.floor(math.log10(abs(value)))))
        return f"{value:.{dec}f}".replace("-", "−")
    sign, whole, frac, sci, _, suffix = m.groups()
    dec = len(frac or "")
    minus = "−" if ("−" in shown or "-" not in shown) else "-"
    if sci:
        mant_text, exp_text = f"{value:.{dec}e}".split("e")  # numpy/python rounding of the mantissa
        exp = int(exp_text)
        text = mant_text
        if sci in ("e", "E"):
            text += f"{sci}{exp:+03d}" if ("+" in shown or "0" in shown.split(sci)[-1][:2]) else f"{sci}{exp}"
            text = text.replace("-", minus)
        else:
            text += sci + str(exp).translate(SUP)
        return text.replace("-", minus) if text.startswith("-") else text
    scale = {"k": 1e3, "M": 1e6, "": 1.0}[suffix]
    text = f"{value / scale:,.{dec}f}" if "," in whole else f"{value / scale:.{dec}f}"
    if text.startswith("-"):
        text = minus + text[1:]
    elif sign == "+":
        text = "+" + text
    return text + suffix


def refresh_docs(dry_run: bool = False) -> int:
    """Rewrite every marker's number from its results file; returns how many changed."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_results_docs import resolve  # noqa: E402  (the test's own reader: one definition)

    changed = 0
    for doc in docs():
        text = doc.read_text()
        problems = []

        def sub(m):
            nonlocal changed
            head, file, key, shown, tail = m.groups()
            try:
                value = resolve(file, key)
                if isinstance(value, str):
                    try:
                        value = float(value)
                    except ValueError:
                        pass
            except (FileNotFoundError, KeyError, IndexError, ValueError) as exc:
                problems.append(f"{file}:{key}: {exc}")
                return m.group(0)
            if value is None:
                problems.append(f"{file}:{key}: no value (null)")
                return m.group(0)
            new = format_like(value, shown)
            if new != shown:
                changed += 1
                print(f"{doc.relative_to(ROOT)}: {file}:{key}: {shown} -> {new}")
            return head + new + tail

        new_text = MARKER.sub(sub, text)
        for p in problems:
            print(f"{doc.relative_to(ROOT)}: cannot resolve {p}", file=sys.stderr)
        if new_text != text and not dry_run:
            doc.write_text(new_text)
    return changed


#: where ``--jobs`` above 1 writes each study's output (``NAME.log``)
LOGS = ROOT / "out" / "regenerate"


def run(study: Study, log: Path | None = None) -> bool:
    """Run one study's command from the repository root; its output to ``log`` when given (else
    this process's own). True when it exits 0."""
    print(f"== {study.name}: {study.command}" + (f" (output: {log})" if log else ""), flush=True)
    t0 = time.perf_counter()
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""), MPLBACKEND="Agg")
    if log is None:
        rc = subprocess.call(study.command, shell=True, cwd=ROOT, env=env)
    else:
        log.parent.mkdir(parents=True, exist_ok=True)
        with open(log, "w") as f:
            rc = subprocess.call(study.command, shell=True, cwd=ROOT, env=env, stdout=f, stderr=subprocess.STDOUT)
    print(f"== {study.name}: exit {rc}, {time.perf_counter() - t0:.0f} s", flush=True)
    return rc == 0


def run_all(todo: list[Study], jobs: int = 1, logs: Path = LOGS) -> list[str]:
    """Run the studies, the non-timing ones ``jobs`` at a time (each one's output to
    ``logs/NAME.log`` when more than one runs), then the timing ones alone, in order; returns the
    names of those that failed."""
    if jobs <= 1:
        return [s.name for s in todo if not run(s)]
    from concurrent.futures import ThreadPoolExecutor

    quiet = [s for s in todo if not s.timing]
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        ok = list(pool.map(lambda s: run(s, logs / f"{s.name}.log"), quiet))
    failed = [s.name for s, good in zip(quiet, ok) if not good]
    return failed + [s.name for s in todo if s.timing and not run(s)]


def select(patterns: list[str], registry=None) -> list[Study]:
    """The registered studies whose names match ``patterns`` (names or shell patterns such as
    ``hidden_mills*``; a pattern leaves out the manual studies, which run only when named), in the
    order given, each once; ``ValueError`` naming a pattern that matches none."""
    registry = REGISTRY if registry is None else registry
    out, unknown = [], []
    for pat in patterns:
        hits = [s for s in registry if s.name == pat or (fnmatch.fnmatchcase(s.name, pat) and not s.manual)]
        if not hits:
            unknown.append(pat)
        out += [s for s in hits if s not in out]
    if unknown:
        raise ValueError(", ".join(unknown))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--list", action="store_true", help="list the registered studies")
    ap.add_argument("--only", nargs="+", metavar="NAME",
                    help="run only these studies (names or shell patterns, e.g. 'hidden_mills*')")
    ap.add_argument("--jobs", type=int, default=1, metavar="N",
                    help="run N studies at a time (the timing ones still alone, last); each one's output goes "
                         "to out/regenerate/NAME.log (default 1: one after the other, output here)")
    ap.add_argument("--no-timings", action="store_true", help="skip the timing benchmarks")
    ap.add_argument("--docs", action="store_true", help="only rewrite the docs' marked numbers from the files")
    ap.add_argument("--dry-run", action="store_true", help="with --docs: show the changes, write nothing")
    a = ap.parse_args(argv)
    if a.list:
        for s in REGISTRY:
            tags = ("timing " if s.timing else "") + ("manual" if s.manual else "")
            print(f"{s.name:30s} ~{s.minutes:5.0f} min  {tags:13s}  {s.command}")
        return 0
    if a.docs:
        n = refresh_docs(a.dry_run)
        print(f"{n} marked numbers {'would change' if a.dry_run else 'changed'}")
        return 0
    if a.jobs < 1:
        print(f"regenerate: error: --jobs: must be >= 1 (got {a.jobs})", file=sys.stderr)
        return 2
    if a.only:
        try:
            todo = select(a.only)
        except ValueError as exc:
            print(f"regenerate: error: --only: unknown study {exc} (see --list)", file=sys.stderr)
            return 2
    else:
        auto = [s for s in REGISTRY if not s.manual]
        todo = [s for s in auto if not s.timing] + ([] if a.no_timings else [s for s in auto if s.timing])
    failed = run_all(todo, a.jobs)
    if failed:
        print(f"regenerate: failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
