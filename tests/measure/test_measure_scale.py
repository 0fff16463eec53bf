"""Scale from metadata and scale bar, data-bar exclusion, overlay, table columns, warnings (bmctl measure)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.measure import read_table, render_micrograph
from bmctl.measure.micrograph import measure_micrograph
from bmctl.measure.scale import find_info_bar, find_scale_bar, nearest_125, scale_from_metadata
from bmctl.measure.segment import segment

DATA = Path(__file__).resolve().parents[1] / "data"
SIO2_TIF = DATA / "sio2_sem_12000x.tif"
needs_sio2 = pytest.mark.skipif(not SIO2_TIF.exists(), reason="SiO2 image not present")


def _cli(capsys, argv):
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


# --- metadata -------------------------------------------------------------------------------------

@needs_sio2
def test_sio2_scale_from_fei_xl_metadata_agrees_with_its_scale_bar():
    # The tag stores magnification 12000 and the display it refers to; the scale bar, measured
    # by hand (tests/data/ATTRIBUTION.md: 136 px between the tick centres = 5 um), gives 36.8 nm/px.
    sc = scale_from_metadata(SIO2_TIF)
    assert sc is not None and sc.source == "metadata" and "34680" in sc.detail
    assert sc.um_per_px == pytest.approx(5.0 / 136.0, rel=0.02)


def _tif(path, **kw):
    tifffile = pytest.importorskip("tifffile")
    a = (np.random.default_rng(0).random((64, 64)) * 255).astype(np.uint8)
    tifffile.imwrite(path, a, **kw)
    return path


@pytest.mark.parametrize(
    "kw, um",
    [
        ({"extratags": [(34682, "s", 0, "[User]\r\nDate=x\r\n[Scan]\r\nPixelWidth=2.5e-08\r\n", True)]}, 0.025),
        ({"extratags": [(34118, "s", 0, "0\r\n\r\nAP_PIXEL_SIZE\r\nImage Pixel Size = 12.5 nm\r\n", True)]}, 0.0125),
        ({"extratags": [(50431, "s", 0, "[MAIN]\r\nPixelSizeX=4e-09\r\n", True)]}, 0.004),
        ({"resolution": (1e5, 1e5), "resolutionunit": "CENTIMETER"}, 0.1),
        ({"imagej": True, "resolution": (20, 20), "metadata": {"unit": "micron"}}, 0.05),
    ],
    ids=["fei-helios", "zeiss", "tescan", "xresolution", "imagej"],
)
def test_vendor_pixel_sizes(tmp_path, kw, um):
    sc = scale_from_metadata(_tif(tmp_path / "a.tif", **kw))
    assert sc is not None and sc.um_per_px == pytest.approx(um, rel=1e-9)


def test_print_resolution_is_not_a_pixel_size(tmp_path):
    assert scale_from_metadata(_tif(tmp_path / "a.tif", resolution=(72, 72), resolutionunit="INCH")) is None


def test_jeol_sidecar(tmp_path):
    from skimage import io

    p = tmp_path / "j.png"
    io.imsave(p, np.zeros((32, 32), np.uint8), check_contrast=False)
    (tmp_path / "j.txt").write_text("$CM_FULL_SIZE 1280 960\n$$SM_MICRON_BAR 160\n$$SM_MICRON_MARKER 5um\n", encoding="utf-8")
    assert scale_from_metadata(p).um_per_px == pytest.approx(5.0 / 160)


def test_nearest_125():
    assert [nearest_125(v) for v in (0.9, 1.6, 4.99, 6.5, 8.0, 180.0)] == [1, 2, 5, 5, 10, 200]


# --- data bar and scale bar -----------------------------------------------------------------------

@needs_sio2
def test_sio2_info_bar_and_scale_bar_found():
    from bmctl.measure import load_image

    img = load_image(SIO2_TIF)
    top = find_info_bar(img)
    assert top == 423  # the black box starts at row 423 (ATTRIBUTION.md)
    bar = find_scale_bar(img, top)
    assert bar is not None and 429 <= bar.row <= 432
    assert bar.length_px == pytest.approx(136, abs=1.5)  # hand-measured tick centres


def _image_with_data_bar(seed=5):
    """A synthetic micrograph with a black data bar: white text blocks and a 100 px scale bar with ticks."""
    m = render_micrograph(np.random.default_rng(seed), n=30, shape=(300, 300), s_px=(14, 24))
    img = np.vstack([m.image, np.zeros((40, 300))])
    img[310:320, 20:60] = 1.0  # "text"
    img[325:328, 150:160] = 1.0
    img[330:332, 100:202] = 1.0  # scale bar rows 330-331, columns 100-201 ...
    img[322:338, 100:102] = 1.0  # ... with 2 px end ticks: 100 px between tick centres
    img[322:338, 200:202] = 1.0
    return m, img


@pytest.mark.slow
def test_data_bar_excluded_and_scale_bar_read():
    m, img = _image_with_data_bar()
    assert find_info_bar(img) == 300
    res = measure_micrograph(img, scale_bar_um=5.0)
    assert res.info_bar_row == 300
    assert res.scale.source == "scale-bar"
    assert res.scale.um_per_px == pytest.approx(5.0 / 100.0, rel=0.01)
    assert res.segmentation.labels.shape[0] == 300  # nothing below the bar's first row is measured
    assert len(res.table) == segment(img, crop="0:300,:").labels.max()
    kept = measure_micrograph(img, um_per_px=0.05, keep_info_bar=True, annotations=False)
    assert kept.info_bar_row is None and len(kept.table) > len(res.table)  # the text counts as particles ...
    drawn = measure_micrograph(img, um_per_px=0.05, keep_info_bar=True)
    assert len(drawn.table) == len(res.table)  # ... unless found as drawn marks (annotations)


def _dark_discs(bg: float = 0.8, level: float = 0.03, shape=(300, 400)):
    """Fifteen dark discs (radius 12 px) in the top 200 rows of a light, noisy field in 8-bit
    levels (as read from a file), and their count."""
    from scipy import ndimage as ndi

    img = np.full(shape, bg)
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    centres = [(40 + 60 * i, 50 + 70 * j) for i in range(3) for j in range(5)]
    for cy, cx in centres:
        img[(yy - cy) ** 2 + (xx - cx) ** 2 < 12 ** 2] = level
    img = ndi.gaussian_filter(img, 1.0) + np.random.default_rng(0).normal(0.0, 0.01, shape)
    return np.round(np.clip(img, 0.0, 1.0) * 255) / 255, len(centres)


def _labels_in(res, y0, y1, x0, x1) -> bool:
    """Whether any measured particle has a pixel in the window (image coordinates)."""
    oy, ox = res.segmentation.offset
    lab = res.segmentation.labels
    full = np.zeros(res.image.shape, lab.dtype)
    full[oy:oy + lab.shape[0], ox:ox + lab.shape[1]] = lab
    return bool(full[y0:y1, x0:x1].any())


def test_thick_scale_bar_found_and_excluded():
    # A 15 px thick dark bar, not at the image's extreme (the particles are darker): it was
    # refused as a bar (more than 10 rows) and measured as one more particle.
    img, n = _dark_discs()
    img[245:260, 150:301] = 0.2
    bar = find_scale_bar(img)
    assert bar is not None and bar.length_px == 151 and (bar.y0, bar.y1) == (245, 259)
    res = measure_micrograph(img, scale_bar_um=1.0)
    assert res.scale.source == "scale-bar" and res.scale.um_per_px == pytest.approx(1.0 / 151)
    assert len(res.table) == n and not _labels_in(res, 240, 265, 145, 306)


def test_scale_bar_in_white_box_found_and_excluded():
    # A white label box holding a 16 px black bar and its "text" (open squares), on a light
    # background: the box was not told from its surroundings and the bar and text were measured
    # as dark particles.
    img, n = _dark_discs(bg=0.78)
    img[222:292, 240:390] = 1.0  # the box
    img[235:251, 265:366] = 0.05  # the bar: 101 px
    for x0 in (280, 300, 320):  # the text below it
        img[262:280, x0:x0 + 12] = 0.05
        img[265:277, x0 + 3:x0 + 9] = 1.0
    bar = find_scale_bar(img)
    assert bar is not None and bar.length_px == 101 and (bar.y0, bar.y1) == (235, 250)
    res = measure_micrograph(img, um_per_px=1.0)
    assert res.segmentation.polarity == "dark"
    assert len(res.table) == n and not _labels_in(res, 220, 294, 238, 392)
    assert res.report()["scale_bar"]["rows"] == [235, 250]


def test_bar_with_label_joined_by_a_tick_is_an_annotation():
    # A thick white bar whose middle tick touches its label (one component, not a rectangle),
    # away from the corners: it was taken for neither a bar nor a glyph beside one.
    from bmctl.measure.annotations import find_annotations

    rng = np.random.default_rng(1)
    img = 0.55 + rng.normal(0.0, 0.02, (400, 400))
    yy, xx = np.mgrid[:400, :400]
    img[(yy - 100) ** 2 + (xx - 200) ** 2 < 25 ** 2] = 1.0  # a saturated round particle
    img[300:315, 120:271] = 1.0  # the bar ...
    img[288:300, 194:197] = 1.0  # ... its tick ...
    img[262:288, 180:210] = 1.0  # ... up to the label: an open square glyph
    img[266:284, 184:206] = 0.55
    ann = find_annotations(img)
    assert ann[307, 130] and ann[307, 260] and ann[294, 195] and ann[263, 195]
    assert not ann[100, 200]


def test_no_data_bar_on_plain_micrograph():
    m = render_micrograph(np.random.default_rng(3), n=30, shape=(300, 300), s_px=(14, 24))
    assert find_info_bar(m.image) is None


def test_array_without_scale_is_an_input_error():
    m = render_micrograph(np.random.default_rng(3), n=10, shape=(128, 128), s_px=(14, 24))
    with pytest.raises(InputError, match="give the scale with um_per_px X"):
        measure_micrograph(m.image)


# --- command line ---------------------------------------------------------------------------------

@pytest.mark.slow
@needs_sio2
def test_cli_sio2_without_scale_or_crop(capsys, tmp_path):
    # Without --um-per-px and --crop: scale from the metadata, data bar excluded. With the bar
    # segmented as particles the count was 52. The source estimates 300-450 spheres from local
    # maxima (tests/data/ATTRIBUTION.md; docs/measurement.md 5.4); fused clusters count as one.
    out = tmp_path / "p.csv"
    rc, stdout, err = _cli(capsys, ["measure", str(SIO2_TIF), "--out", str(out)])
    assert rc == 0, err
    lines = out.read_text(encoding="utf-8").splitlines()
    assert lines[0] == "particle_id,image,x_um,y_um,area_um2,perimeter_um,s_um,r"
    t = read_table(out)
    assert 300 <= len(t) <= 600
    assert 0.3 <= np.median(t.s_um) <= 0.9
    doc = json.loads((tmp_path / "measure.json").read_text(encoding="utf-8"))
    entry = doc["inputs"][0]
    assert entry["scale"]["source"] == "metadata" and entry["info_bar_first_row"] == 423
    assert entry["scale_bar"]["length_um_at_this_scale"] == pytest.approx(5.0, rel=0.03)
    assert (tmp_path / "sio2_sem_12000x.overlay.png").stat().st_size > 10_000
    ys = np.array([float(ln.split(",")[3]) for ln in lines[1:]])
    assert ys.max() < 423 * 0.0368  # no particle centroid in the data bar


def test_cli_no_scale_one_line_exit_2(capsys, tmp_path):
    from skimage import io

    m = render_micrograph(np.random.default_rng(21), n=10, shape=(128, 128), s_px=(16, 28))
    p = tmp_path / "plain.png"
    io.imsave(p, (m.image * 255).astype(np.uint8), check_contrast=False)
    rc, _, err = _cli(capsys, ["measure", str(p), "--out", str(tmp_path / "o.csv")])
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "--um-per-px" in lines[0] and "--scale-bar-um" in lines[0]
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.slow
def test_cli_overlay_columns_and_ids(capsys, tmp_path):
    from skimage import io

    m = render_micrograph(np.random.default_rng(21), n=20, shape=(200, 200), s_px=(16, 28))
    p = tmp_path / "syn.png"
    io.imsave(p, (m.image * 255).astype(np.uint8), check_contrast=False)
    (tmp_path / "b").mkdir()
    q = tmp_path / "b" / "syn.png"  # another file of the same name (one file twice is refused: counted twice)
    q.write_bytes(p.read_bytes())
    out = tmp_path / "o" / "p.csv"
    rc, _, err = _cli(capsys, ["measure", str(p), str(q), "--um-per-px", "0.5", "--out", str(out)])
    assert rc == 0, err
    rows = [ln.split(",") for ln in out.read_text(encoding="utf-8").splitlines()]
    assert rows[0][:4] == ["particle_id", "image", "x_um", "y_um"]
    ids = [int(r[0]) for r in rows[1:]]
    assert ids == list(range(1, len(ids) + 1))  # unique over the pooled images
    xy = np.array([[float(r[2]), float(r[3])] for r in rows[1:]])
    assert xy.min() > 0 and xy.max() < 200 * 0.5
    # centroids agree with the truth: each measured particle lies on a placed particle's centre
    first = xy[: len(xy) // 2] / 0.5  # px
    centres = m.centres_px[:, ::-1]  # (x, y)
    d = np.min(np.hypot(first[:, None, 0] - centres[None, :, 0], first[:, None, 1] - centres[None, :, 1]), axis=1)
    assert np.median(d) < 1.0
    assert (tmp_path / "o" / "syn.overlay.png").exists() and (tmp_path / "o" / "syn-2.overlay.png").exists()
    assert len(read_table(out)) == len(ids)  # the new layout reads back


# --- warnings -------------------------------------------------------------------------------------

def test_clean_image_has_no_warnings():
    m = render_micrograph(np.random.default_rng(4), n=25, shape=(320, 320), s_px=(20, 30))
    assert [w.code for w in measure_micrograph(m.image, um_per_px=1.0).warnings] == []


@pytest.mark.slow
def test_small_particles_and_border_cuts_warn(capsys, tmp_path):
    small = render_micrograph(np.random.default_rng(6), n=120, shape=(256, 256), s_px=(6, 9))
    codes = {w.code for w in measure_micrograph(small.image, um_per_px=1.0, min_area_px=15).warnings}
    assert "small" in codes
    big = render_micrograph(np.random.default_rng(7), n=40, shape=(400, 400), s_px=(40, 60))
    cut = big.image[50:210, 50:210]  # a window that cuts many particles
    codes = {w.code for w in measure_micrograph(cut, um_per_px=1.0).warnings}
    assert "border" in codes
    from skimage import io

    p = tmp_path / "cut.png"
    io.imsave(p, (cut * 255).astype(np.uint8), check_contrast=False)
    rc, _, err = _cli(capsys, ["measure", str(p), "--um-per-px", "1", "--out", str(tmp_path / "c.csv")])
    assert rc == 0 and "bmctl: warning:" in err and "border" in err
    doc = json.loads((tmp_path / "measure.json").read_text(encoding="utf-8"))
    assert "border" in {w["code"] for w in doc["inputs"][0]["warnings"]}
