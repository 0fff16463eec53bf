"""Automatic polarity, drawn annotations, the reliability verdict, and its use in ``campaign
sample`` and ``estimate``.

Real-image checks compare with the hand-made instance masks of three EMPS micrographs
(tests/data/ATTRIBUTION.md): found particles are matched one-to-one to mask instances at
IoU > 0.5; instances cut by the image border or below 30 px are not counted (the measurement
drops those by design). These three images are among the 40 the parameters were chosen on
(docs/measurement.md "EMPS benchmark"), so the limits guard against regressions; the
out-of-sample numbers are the benchmark's held-out half.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage as ndi

from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.measure.annotations import find_annotations
from bmctl.measure.micrograph import check_verdicts, measure_micrograph, table_reports
from bmctl.measure.polarity import polarity_vote
from bmctl.measure.quality import MIN_PARTICLES, VERDICT_LIMITS, verdict
from bmctl.measure.render import render_micrograph
from bmctl.measure.segment import measure_labels, segment
from bmctl.validation.measure import match_labels

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"

DATA = Path(__file__).resolve().parents[1] / "data"
DARK_TEM = DATA / "065d8e352c.png"  # dark nanoparticles (TEM), black "200 nm" and bar
BRIGHT_SEM = DATA / "43875c5b20.png"  # bright particles (SEM), white "(d)", "200 nm" and bar
TEXTURED = DATA / "9fac661e24.png"  # faint dark rings on a strong background texture
needs_emps = pytest.mark.skipif(not (DARK_TEM.exists() and BRIGHT_SEM.exists() and TEXTURED.exists()),
                                reason="EMPS test images not present")


def _score(path: Path, **kw) -> dict:
    """bmctl measure at 1 px = 1 unit against the image's hand masks."""
    from skimage import io
    from skimage.segmentation import relabel_sequential

    res = measure_micrograph(path, um_per_px=1.0, **kw)
    ref = relabel_sequential(io.imread(path.with_suffix(".seg.png")).astype(np.int64))[0]
    found = np.zeros(ref.shape, np.int64)
    oy, ox = res.segmentation.offset
    lab = res.segmentation.labels
    found[oy:oy + lab.shape[0], ox:ox + lab.shape[1]] = lab
    area = np.bincount(ref.ravel())
    counted = area >= 30
    counted[0] = False
    counted[np.unique(np.r_[ref[0], ref[-1], ref[:, 0], ref[:, -1]])] = False
    i_f, i_r, _ = match_labels(found, ref)
    ignored = i_f[~counted[i_r]]
    i_f, i_r = i_f[counted[i_r]], i_r[counted[i_r]]
    n_found = int(lab.max()) - ignored.size
    tp = i_f.size
    ratio = float(np.median(measure_labels(found, 1.0).s_um[i_f - 1] / measure_labels(ref, 1.0).s_um[i_r - 1])) if tp else float("nan")
    return {"res": res, "precision": tp / max(n_found, 1), "recall": tp / int(counted.sum()), "size_ratio": ratio}


# --- polarity ---------------------------------------------------------------------------------------

def test_polarity_vote_on_synthetic_particles_both_ways():
    m = render_micrograph(np.random.default_rng(3), n=30, shape=(300, 300), s_px=(14, 24))
    assert polarity_vote(m.image) > 0.6
    assert polarity_vote(1.0 - m.image) < 0.4


def test_dark_particles_found_without_a_flag():
    m = render_micrograph(np.random.default_rng(4), n=30, shape=(300, 300), s_px=(14, 24))
    bright, dark = segment(m.image), segment(1.0 - m.image)
    assert (bright.polarity, dark.polarity) == ("bright", "dark")
    assert bright.polarity_source == dark.polarity_source == "edges"
    assert dark.labels.max() == bright.labels.max() == len(m.truth)
    forced = segment(1.0 - m.image, polarity="bright")  # the override is obeyed
    assert forced.polarity_source == "user" and forced.labels.max() < len(m.truth) // 2


def test_polarity_flag_is_checked():
    with pytest.raises(InputError, match="polarity"):
        segment(np.zeros((64, 64)), polarity="grey")


# --- annotations ------------------------------------------------------------------------------------

def test_scale_bar_and_word_found_round_particle_kept():
    img = np.full((200, 300), 0.4)
    yy, xx = np.mgrid[:200, :300]
    img[(yy - 60) ** 2 + (xx - 150) ** 2 < 20 ** 2] = 1.0  # a saturated round particle
    img[180:185, 180:280] = 1.0  # scale bar
    for x0 in (190, 215, 240):  # a "word" of three glyphs above it: open squares (thin, not convex)
        img[155:175, x0:x0 + 16] = 1.0
        img[158:175, x0 + 3:x0 + 13] = 0.4
    ann = find_annotations(img)
    assert ann[182, 230] and ann[165, 192] and ann[165, 242]
    assert not ann[60, 150]


# --- real micrographs with hand masks ---------------------------------------------------------------

@needs_emps
def test_dark_tem_against_hand_masks():
    # measured: dark from the edge vote, precision 0.94, recall 0.91, size ratio 0.79 (the masks
    # include the particles' blurred rim: the 50 % contour of a 13 px particle is ~1.5 px inside)
    s = _score(DARK_TEM)
    seg = s["res"].segmentation
    assert (seg.polarity, seg.polarity_source) == ("dark", "edges")
    assert s["precision"] >= 0.8 and s["recall"] >= 0.8
    assert 0.7 <= s["size_ratio"] <= 1.05
    assert s["res"].verdict == "ok"


@needs_emps
def test_bright_sem_with_panel_letter_against_hand_masks():
    # measured: bright, precision 1.00, recall 0.93, size ratio 0.95; before the annotation mask
    # the white "(d)" and "200 nm" took the threshold and no particle was found (F1 0)
    s = _score(BRIGHT_SEM)
    seg = s["res"].segmentation
    assert seg.polarity == "bright" and seg.annotation_px > 1000
    assert s["precision"] >= 0.85 and s["recall"] >= 0.85
    assert 0.9 <= s["size_ratio"] <= 1.1
    wrong = _score(BRIGHT_SEM, polarity="dark")  # the override is obeyed, and the verdict sees it
    assert wrong["recall"] < 0.2 and wrong["res"].verdict != "ok"


@needs_emps
def test_textured_image_is_flagged():
    # faint rings on a background texture as strong as they are: nothing usable is measured (F1 0)
    res = measure_micrograph(TEXTURED, um_per_px=1.0)
    assert res.verdict == "unusable"
    assert res.report()["verdict"]["value"] == "unusable"


# --- the verdict ------------------------------------------------------------------------------------

def _unusable_image() -> np.ndarray:
    """Five round particles inside, and large ones cut by every edge: most of the foreground is unmeasured."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:200, :200]
    img = np.full((200, 200), 0.2)
    discs = [(100, 100, 10), (60, 100, 9), (140, 100, 9), (100, 55, 8), (100, 145, 8)]
    for t in range(25, 200, 50):
        discs += [(0, t, 22), (199, t, 22), (t, 0, 22), (t, 199, 22)]
    for cy, cx, r in discs:
        img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = 0.8
    return ndi.gaussian_filter(img, 1.0) + rng.normal(0, 0.02, img.shape)


def test_verdict_ok_on_clean_synthetic_and_unusable_when_most_is_unmeasured():
    m = render_micrograph(np.random.default_rng(1), n=40, shape=(320, 320), s_px=(14, 28))
    clean = measure_micrograph(m.image, um_per_px=1.0)
    assert clean.verdict == "ok" and clean.verdict_reasons == []
    bad = measure_micrograph(_unusable_image(), um_per_px=1.0)
    assert len(bad.table) == 5
    assert bad.verdict == "unusable" and "foreground" in bad.verdict_reasons[0]


def test_verdict_rules():
    base = {"count": 30, "polarity_margin": 0.3, "merged": 0.0, "at_limit": 0.1, "min_area_jump": 0.0, "unsegmented": 0.1}
    assert verdict(base)[0] == "ok"
    for key, bad in (("polarity_margin", 0.01), ("merged", 0.5), ("at_limit", 0.6), ("min_area_jump", 0.9), ("unsegmented", 0.6)):
        assert verdict({**base, key: bad})[0] == "doubtful", key
    assert verdict({**base, "merged": 0.5, "at_limit": 0.6})[0] == "unusable"
    assert verdict({**base, "unsegmented": 0.85})[0] == "unusable"
    assert verdict({**base, "polarity_margin": None})[0] == "ok"  # polarity given: no vote to judge
    assert set(VERDICT_LIMITS) <= set(base)


def test_verdict_few_particles_doubtful_never_unusable():
    base = {"count": 30, "polarity_margin": 0.3, "merged": 0.0, "at_limit": 0.1, "min_area_jump": 0.0, "unsegmented": 0.1}
    for n in (1, 2, MIN_PARTICLES - 1):
        value, reasons = verdict({**base, "count": n})
        assert value == "doubtful" and reasons == [f"few particles: {n} found (fewer than {MIN_PARTICLES}); statistics unreliable"]
    assert verdict({**base, "count": MIN_PARTICLES}) == ("ok", [])
    assert verdict({**base, "count": 2}, min_particles=0) == ("ok", [])
    assert verdict({**base, "count": 2}, min_particles=2) == ("ok", [])
    # on top of a segmentation doubt it is listed, but does not make the image unusable (still accepted)
    value, reasons = verdict({**base, "count": 2, "merged": 0.5})
    assert value == "doubtful" and len(reasons) == 2 and reasons[-1].startswith("few particles: 2 found")
    assert verdict({**base, "count": 2, "unsegmented": 0.9})[0] == "unusable"
    assert verdict({**base, "count": 0})[0] == "unusable"
    from bmctl.commands import measure as cmd

    assert cmd.MIN_PARTICLES == MIN_PARTICLES  # the command's default, kept there without the image stack


def _two_particles() -> np.ndarray:
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[:160, :160]
    img = np.full((160, 160), 0.2)
    for cy, cx in ((50, 60), (110, 100)):
        img[(yy - cy) ** 2 + (xx - cx) ** 2 < 14 ** 2] = 0.8
    return ndi.gaussian_filter(img, 1.0) + rng.normal(0, 0.01, img.shape)


def test_few_particles_image_is_doubtful_and_still_accepted():
    # Two clean particles: the segmentation is right, the verdict was "ok"; two particles say
    # next to nothing about a size distribution.
    res = measure_micrograph(_two_particles(), um_per_px=1.0)
    assert len(res.table) == 2
    assert res.verdict == "doubtful"
    assert res.verdict_reasons == [f"few particles: 2 found (fewer than {MIN_PARTICLES}); statistics unreliable"]
    rep = res.report()
    assert rep["verdict"] == {"value": "doubtful", "reasons": res.verdict_reasons}
    lines = check_verdicts([{**rep, "image": "two.png"}])  # estimate, campaign sample, calibrate: warned, not refused
    assert lines == [f"two.png: verdict doubtful (few particles: 2 found (fewer than {MIN_PARTICLES}); statistics "
                     "unreliable): check its overlay before trusting its particles"]
    assert measure_micrograph(_two_particles(), um_per_px=1.0, min_particles=0).verdict == "ok"
    with pytest.raises(InputError, match=r"^min_particles: expected a whole number >= 0 \(got -1\)$"):
        measure_micrograph(_two_particles(), um_per_px=1.0, min_particles=-1)


def test_cli_few_particles_verdict_and_flag(tmp_path, capsys):
    p = _save(tmp_path / "two.png", _two_particles())
    out = tmp_path / "m" / "p.csv"
    assert main(["measure", str(p), "--um-per-px", "1", "--out", str(out)]) == 0
    assert "verdict doubtful (few particles: 2 found" in capsys.readouterr().err
    assert table_reports(out)[0]["verdict"]["value"] == "doubtful"
    assert main(["measure", str(p), "--um-per-px", "1", "--min-particles", "0"]) == 0
    assert "verdict ok" in capsys.readouterr().err
    assert main(["measure", str(p), "--um-per-px", "1", "--min-particles", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--min-particles: must be >= 0 (got -1)" in err[0]


def test_check_verdicts_refuses_unusable_unless_accepted():
    reps = [{"image": "a.png", "verdict": {"value": "ok", "reasons": []}},
            {"image": "b.png", "verdict": {"value": "unusable", "reasons": ["91% of the foreground in no measured particle"]}}]
    with pytest.raises(InputError, match=r"b.png: verdict unusable .*--accept-unusable"):
        check_verdicts(reps)
    assert check_verdicts(reps, accept_unusable=True) == [
        "b.png: verdict unusable (91% of the foreground in no measured particle): check its overlay before trusting its particles"]



def test_hand_edited_measure_json_is_no_traceback(tmp_path):
    """A measure.json beside a table with ``inputs`` or ``reasons`` of another type was a TypeError
    traceback in estimate, campaign sample and calibrate."""
    (tmp_path / "t.csv").write_text("x", encoding="utf-8")
    for inputs in (5, None, "abc", {"a": 1}):
        (tmp_path / "measure.json").write_text(json.dumps({"table": "t.csv", "inputs": inputs}), encoding="utf-8")
        assert table_reports(tmp_path / "t.csv") == []
    for reasons, why in ((5, "5"), (None, ""), ("dark", "dark")):
        with pytest.raises(InputError, match=rf"a.png: verdict unusable \({why}\)"):
            check_verdicts([{"image": "a.png", "verdict": {"value": "unusable", "reasons": reasons}}])
    assert check_verdicts([{"image": "a.png", "verdict": {"value": "doubtful", "reasons": None}}]) == [
        "a.png: verdict doubtful (): check its overlay before trusting its particles"]

# --- command line, campaign, estimate ---------------------------------------------------------------

def _lab_campaign(tmp_path: Path) -> Path:
    """A fresh campaign on the lab card with the 300 rpm recipe (target d50 45 µm)."""
    from bmctl import campaign as cp

    d = tmp_path / "c"
    cp.init(d, CARD, RECIPE, {"d50_um": 45.0})
    return d


def _measured_estimate_args(image: Path, tmp_path: Path, capsys) -> list[str]:
    """``bmctl measure`` the image (1 µm/px) to a table; the ``bmctl estimate`` arguments that read it at 0 h."""
    out = tmp_path / "m" / "p.csv"
    assert main(["measure", str(image), "--um-per-px", "1", "--out", str(out)]) == 0
    capsys.readouterr()
    return ["estimate", str(CARD), "--samples", str(out), "--times", "0", "--particles", "200", "--out",
            str(tmp_path / "e" / "e.csv")]


def _save(path: Path, img: np.ndarray) -> Path:
    from skimage import io

    io.imsave(path, (np.clip(img, 0, 1) * 255).astype(np.uint8), check_contrast=False)
    return path


def test_cli_reports_polarity_and_verdict(tmp_path, capsys):
    p = _save(tmp_path / "dark.png", 1.0 - render_micrograph(np.random.default_rng(2), n=20, shape=(256, 256), s_px=(16, 26)).image)
    assert main(["measure", str(p), "--um-per-px", "1", "--out", str(tmp_path / "out" / "p.csv")]) == 0
    err = capsys.readouterr().err
    assert "dark particles (edge vote" in err and "verdict ok" in err
    doc = json.loads((tmp_path / "out" / "measure.json").read_text(encoding="utf-8"))
    entry = doc["inputs"][0]
    assert entry["polarity"]["value"] == "dark" and entry["verdict"]["value"] == "ok"
    assert set(VERDICT_LIMITS) <= set(entry["evidence"])
    assert table_reports(tmp_path / "out" / "p.csv")[0]["verdict"]["value"] == "ok"
    assert table_reports(tmp_path / "other.csv") == []


def test_cli_dark_and_bright_flags_exclusive(capsys):
    assert main(["measure", "x.png", "--dark-particles", "--bright-particles"]) == 2
    assert "not allowed with" in capsys.readouterr().err


@pytest.mark.slow
def test_campaign_sample_refuses_unusable_image(tmp_path):
    from bmctl import campaign as cp

    d = _lab_campaign(tmp_path)
    bad = _save(tmp_path / "bad.png", _unusable_image())
    with pytest.raises(InputError, match="verdict unusable"):
        cp.sample(d, 0.0, [str(bad)], um_per_px=1.0)
    assert cp.status(d)["counts"]["samples"] == 0  # nothing stored
    r = cp.sample(d, 0.0, [str(bad)], um_per_px=1.0, accept_unusable=True)
    assert r["n"] == 5 and "verdict unusable" in r["warnings"][0]


@pytest.mark.slow
def test_estimate_refuses_unusable_table_from_measure(tmp_path, capsys):
    bad = _save(tmp_path / "bad.png", _unusable_image())
    args = _measured_estimate_args(bad, tmp_path, capsys)
    assert main(args) == 2
    assert "verdict unusable" in capsys.readouterr().err
    assert not (tmp_path / "e").exists()
    assert main(args + ["--accept-unusable"]) == 0
    assert "verdict unusable" in capsys.readouterr().err


@pytest.mark.slow
def test_campaign_sample_and_estimate_accept_few_particles_with_warning(tmp_path, capsys):
    from bmctl import campaign as cp

    d = _lab_campaign(tmp_path)
    two = _save(tmp_path / "two.png", _two_particles())
    r = cp.sample(d, 0.0, [str(two)], um_per_px=1.0)
    assert r["n"] == 2 and any("verdict doubtful (few particles: 2 found" in w for w in r["warnings"])
    assert cp.status(d)["counts"]["samples"] == 1  # stored
    args = _measured_estimate_args(two, tmp_path, capsys)
    assert main(args) == 0
    assert "verdict doubtful (few particles: 2 found" in capsys.readouterr().err
