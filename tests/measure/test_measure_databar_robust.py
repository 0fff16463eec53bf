"""Data-bar detection on degraded SEM images (bmctl measure, docs/measurement.md Sec. 8.1).

The SiO2 micrograph of ``tests/data`` (its black data bar in rows 423-462) is saved again as a
JPEG (quality 75), blurred (Gaussian, sigma 1 px) and recomposed with its data bar at the top
(a banner, rows 0-39), all in ``tmp_path``. The bar must still be found and excluded, and the
particles measured must stay close to those of the original image: count within
``COUNT_TOL`` and median s within ``MEDIAN_TOL`` of the clean image's; and within
``SAME_IMAGE_TOL`` of the same degraded image cropped by hand above its bar. With the modal
value alone (no tolerance at the extremes, no search at the top) the JPEG's bar was found at
row 432 (230 particles, median s +52 %), the blurred image's at row 440 (357 particles), and
6 "particles" were measured in the banner's text.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage as ndi

from bmctl.measure import load_image, render_micrograph
from bmctl.measure.micrograph import measure_micrograph
from bmctl.measure.scale import find_info_bar

DATA = Path(__file__).resolve().parent.parent / "data"
SIO2_TIF = DATA / "sio2_sem_12000x.tif"
pytestmark = pytest.mark.skipif(not SIO2_TIF.exists(), reason="SiO2 image not present")

BAR_FIRST, BAR_LAST = 423, 462  # the black data bar of the SiO2 image (tests/data/ATTRIBUTION.md)
UM_PER_PX = 0.03666  # its metadata scale (the PNG and JPEG copies carry no metadata)
SCALE_BAR_PX = 136  # its 5 um scale bar, between the tick centres (hand-measured)
COUNT_TOL = 0.15  # particle count vs the clean image (blurring merges and loses faint spheres: -11 %)
MEDIAN_TOL = 0.12  # median s vs the clean image (blurred: +9 %)
SAME_IMAGE_TOL = 0.03  # count and median s vs the same degraded image cropped by hand above its bar


def _pixels() -> np.ndarray:
    return np.asarray(Image.open(SIO2_TIF).convert("L"))


def _jpeg(path: Path) -> Path:
    out = path / "sio2_q75.jpg"
    Image.fromarray(_pixels()).save(out, quality=75)
    return out


def _blurred(path: Path) -> Path:
    out = path / "sio2_blur1.png"
    blur = ndi.gaussian_filter(_pixels().astype(float), 1.0)
    Image.fromarray(np.clip(np.round(blur), 0, 255).astype(np.uint8)).save(out)
    return out


def _banner(path: Path) -> Path:
    """The data bar moved to the top: its rows above the micrograph's."""
    a = _pixels()
    out = path / "sio2_banner.png"
    Image.fromarray(np.vstack([a[BAR_FIRST:BAR_LAST + 1], a[:BAR_FIRST]])).save(out)
    return out


def _close(res, ref, tol_count, tol_median):
    n, ref_n = len(res.table), len(ref.table)
    s, ref_s = float(np.median(res.table.s_um)), float(np.median(ref.table.s_um))
    assert abs(n / ref_n - 1.0) <= tol_count, (n, ref_n)
    assert abs(s / ref_s - 1.0) <= tol_median, (s, ref_s)


@pytest.fixture(scope="module")
def clean():
    res = measure_micrograph(SIO2_TIF)
    assert res.info_bar_row == BAR_FIRST and res.info_bar_top_last_row is None
    return res


@pytest.mark.parametrize("make, rows", [(_jpeg, (BAR_FIRST, BAR_FIRST)), (_blurred, (BAR_FIRST, BAR_FIRST + 2))],
                         ids=["jpeg-q75", "blur-sigma1"])
def test_degraded_data_bar_found_and_excluded(make, rows, clean, tmp_path):
    path = make(tmp_path)
    img = load_image(path)
    first = find_info_bar(img)
    assert first is not None and rows[0] <= first <= rows[1]
    assert find_info_bar(img, side="top") is None
    res = measure_micrograph(path, um_per_px=UM_PER_PX)
    rep = res.report()
    assert rep["info_bar_first_row"] == first and rep["info_bar_top_last_row"] is None
    assert res.segmentation.labels.shape[0] == first  # nothing from the bar's first row down is measured
    assert res.scale_bar is not None and BAR_FIRST <= res.scale_bar.row <= BAR_LAST
    assert res.scale_bar.length_px == pytest.approx(SCALE_BAR_PX, abs=1.5)
    _close(res, clean, COUNT_TOL, MEDIAN_TOL)
    by_hand = measure_micrograph(path, um_per_px=UM_PER_PX, keep_info_bar=True, crop=f"0:{BAR_FIRST},:")
    _close(res, by_hand, SAME_IMAGE_TOL, SAME_IMAGE_TOL)


def test_data_bar_at_the_top_found_and_excluded(clean, tmp_path):
    path = _banner(tmp_path)
    img = load_image(path)
    n_bar = BAR_LAST - BAR_FIRST + 1
    assert find_info_bar(img) is None
    assert find_info_bar(img, side="top") == n_bar - 1  # the banner's last row
    res = measure_micrograph(path, um_per_px=UM_PER_PX)
    rep = res.report()
    assert rep["info_bar_first_row"] is None and rep["info_bar_top_last_row"] == n_bar - 1
    assert res.segmentation.offset[0] == n_bar  # the frame starts below the banner
    assert res.y_um.min() > n_bar * UM_PER_PX
    assert res.scale_bar is not None and res.scale_bar.row < n_bar  # found in the banner
    assert res.scale_bar.length_px == pytest.approx(SCALE_BAR_PX, abs=1.5)
    _close(res, clean, 0.02, 0.02)  # the same micrograph pixels as the clean image above its bar
    # with --crop the banner is masked instead
    masked = measure_micrograph(path, um_per_px=UM_PER_PX, crop=f"0:{img.shape[0]},:")
    assert masked.info_bar_top_last_row == n_bar - 1 and masked.y_um.min() > n_bar * UM_PER_PX
    kept = measure_micrograph(path, um_per_px=UM_PER_PX, keep_info_bar=True, annotations=False)
    assert kept.info_bar_top_last_row is None
    assert (kept.y_um < n_bar * UM_PER_PX).any()  # kept, its text is measured as particles


def test_no_data_bar_on_images_without_one(tmp_path):
    a = _pixels()[:BAR_FIRST]  # the micrograph above its bar
    plain = tmp_path / "plain.png"
    Image.fromarray(a).save(plain)
    jpeg = tmp_path / "plain.jpg"
    Image.fromarray(a).save(jpeg, quality=75)
    blur = tmp_path / "plain_blur.png"
    Image.fromarray(np.clip(np.round(ndi.gaussian_filter(a.astype(float), 1.0)), 0, 255).astype(np.uint8)).save(blur)
    synthetic = render_micrograph(np.random.default_rng(3), n=30, shape=(300, 300), s_px=(14, 24)).image
    images = [load_image(p) for p in (plain, jpeg, blur)] + [synthetic]
    # real micrographs with smooth backgrounds, panel letters and scale bars (no data bar)
    images += [load_image(p) for p in sorted(DATA.glob("*.png")) if not p.name.endswith(".seg.png")]
    for img in images:
        assert find_info_bar(img) is None and find_info_bar(img, side="top") is None


def test_the_cli_names_and_shades_a_top_bar(tmp_path, capsys):
    from bmctl.cli import main

    path = _banner(tmp_path)
    n_bar = BAR_LAST - BAR_FIRST + 1
    out = tmp_path / "m" / "particles.csv"
    assert main(["measure", str(path), "--um-per-px", str(UM_PER_PX), "--out", str(out), "--no-progress"]) == 0
    assert f"data bar rows 0-{n_bar - 1} excluded" in capsys.readouterr().out
    png = np.asarray(Image.open(out.parent / "sio2_banner.overlay.png").convert("RGB")).astype(int)
    bar = png[: png.shape[0] * n_bar // (n_bar + BAR_FIRST) - 2]  # the banner's rows, shaded red
    below = png[png.shape[0] // 2:]
    red = lambda a: float(np.mean(a[..., 0] - a[..., 1]))  # noqa: E731
    assert red(bar) > red(below) + 20, (red(bar), red(below))
