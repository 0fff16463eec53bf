"""`bmctl measure` on micrographs it was not tuned on: huge frames, narrow-range and float images,
images where nothing is found."""

from __future__ import annotations

import numpy as np
from PIL import Image

from bmctl.cli import main


def _discs(size: int = 128) -> np.ndarray:
    """A gray uint8 image: bright discs (radius 7 px) on a dark background, every 40 px."""
    img = np.full((size, size), 30, np.uint8)
    yy, xx = np.mgrid[:size, :size]
    for cy in range(24, size - 16, 40):
        for cx in range(24, size - 16, 40):
            img[(yy - cy) ** 2 + (xx - cx) ** 2 <= 49] = 220
    return img


def test_measure_refuses_an_image_over_the_memory_budget_before_decoding(tmp_path, capsys, monkeypatch):
    img = tmp_path / "big.png"
    Image.fromarray(_discs(256)).save(img)
    out = tmp_path / "o" / "t.csv"
    monkeypatch.setenv("BMCTL_BUDGET_MEMORY_GB", "0.01")  # 10 MiB: a 256 x 256 frame needs more to segment
    assert main(["measure", str(img), "--um-per-px", "0.5", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "big.png (65,536 px" in err and "over the budget" in err, err
    assert "--budget-memory-gb" in err
    assert not out.parent.exists()
    assert main(["measure", str(img), "--um-per-px", "0.5", "--budget-memory-gb", "1", "--out", str(out)]) == 0
    assert out.is_file()


def test_overlay_of_a_narrow_range_16_bit_image_shows_its_particles(tmp_path, capsys):
    img = tmp_path / "narrow.png"
    Image.fromarray((10_000 + (_discs(128).astype(np.uint16) - 30) * 2).astype(np.uint16)).save(img)  # 380 of 65,536 levels
    out = tmp_path / "o" / "t.csv"
    assert main(["measure", str(img), "--um-per-px", "0.5", "--out", str(out)]) == 0
    capsys.readouterr()
    ov = np.asarray(Image.open(out.parent / "narrow.overlay.png").convert("RGB")).astype(int)
    gray = ov[(ov[..., 0] == ov[..., 1]) & (ov[..., 1] == ov[..., 2])][:, 0]  # not the outlines, ids or title
    lo, hi = np.percentile(gray, [1, 99])
    assert hi - lo > 150, (lo, hi)  # discs and background apart, not one flat gray


def test_no_particle_found_names_what_finds_particles_not_the_scale(tmp_path, capsys):
    img = np.full((96, 96), 30, np.uint8)
    yy, xx = np.mgrid[:96, :96]
    img[(yy - 48) ** 2 + xx ** 2 <= 400] = 220  # one disc, cut by the left edge: no whole particle
    path = tmp_path / "cut.png"
    Image.fromarray(img).save(path)
    assert main(["measure", str(path), "--um-per-px", "0.5", "--out", str(tmp_path / "o" / "t.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cut.png: no particles found" in err, err
    assert "scale" not in err  # the pixel size plays no part in finding particles
    assert "particles (" in err and "--min-area-px" in err and "--dark-particles" in err  # how it was read, what to try
    assert not (tmp_path / "o").exists()


def test_a_16_bit_frame_of_a_10_bit_detector_measures_as_its_8_bit_copy(tmp_path):
    """A 16-bit TIFF holding 10-bit data (values 0..1023) was scaled by 65,535: its whole range
    fell within the segmentation's 8-bit saturation floor and a clean powder field came out with
    2 particles, verdict unusable; its 8-bit copy gives the full count."""
    from pathlib import Path

    import tifffile

    from bmctl.measure.micrograph import measure_micrograph

    data = Path(__file__).resolve().parents[1] / "data" / "ampis_powder_b.png"
    img8 = np.asarray(Image.open(data).convert("L"))[:512, :768]
    tifffile.imwrite(tmp_path / "ten_bit.tif", img8.astype(np.uint16) * 4)
    ref = measure_micrograph(img8, um_per_px=0.1)
    got = measure_micrograph(tmp_path / "ten_bit.tif", um_per_px=0.1)
    assert len(ref.table) >= 20
    assert got.verdict == ref.verdict and len(got.table) == len(ref.table)
    assert np.allclose(np.sort(got.table.s_um), np.sort(ref.table.s_um))


def test_a_float_export_of_a_narrow_range_measures_as_its_8_bit_copy(tmp_path):
    """A 32-bit float TIFF (an ImageJ export) holding gray levels 0.40-0.45 was taken as it was: its
    range spans under 13 of the segmentation's 8-bit levels and the AMPIS field lost a sixth of its
    particles (128 of 155). Read from a file, real pixels are scaled over their own range."""
    from pathlib import Path

    import tifffile

    from bmctl.measure.micrograph import measure_micrograph

    data = Path(__file__).resolve().parents[1] / "data" / "ampis_powder_b.png"
    img8 = np.asarray(Image.open(data).convert("L"))[:512, :768]
    lo, hi = float(img8.min()), float(img8.max())
    tifffile.imwrite(tmp_path / "narrow.tif", (0.40 + 0.05 * (img8 - lo) / (hi - lo)).astype(np.float32))
    ref = measure_micrograph(img8, um_per_px=0.1)
    got = measure_micrograph(tmp_path / "narrow.tif", um_per_px=0.1)
    assert len(ref.table) >= 20
    assert got.verdict == ref.verdict and len(got.table) == len(ref.table)
    assert np.allclose(np.sort(got.table.s_um), np.sort(ref.table.s_um), rtol=1e-3)
