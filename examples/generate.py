"""Generate the example data set of examples/ from the stochastic plant (seeded).

    python examples/generate.py            # rewrites examples/samples/*.csv, readings.csv, micrograph-2h.tif

An Al-Ni 1:1 mill that bonds 25 % more and fractures 15 % less than the lab card says
(``gamma x 1.25, delta x 0.85``, the hidden truth that ``bmctl estimate`` and ``bmctl
calibrate`` should find) runs 8 h at 300 rpm without rest. At 0.5, 1, 2, 4 and 8 h a
micrograph's worth of 300 particles is measured (:func:`bmctl.measure.sampler.micrograph_sample`,
its segmentation noise) and written as a particle table; the vial temperature at the same
times goes to ``readings.csv`` (read to 0.1 degC). At 2 h, 60 of the plant's particles are
also rendered as a synthetic SEM-like micrograph (1.5 µm per px, stored as an ImageJ TIFF
calibration so that ``bmctl measure`` reads the scale). Every draw comes from one
SeedSequence (``SEED``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = Path(__file__).resolve().parent
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
SEED = 7
GAMMA_MULT, DELTA_MULT = 1.25, 0.85  # the example mill against the card (hidden truth)
RPM = 300.0
TIMES_H = (0.5, 1.0, 2.0, 4.0, 8.0)
PARTICLES = 4000  # simulated particles in the mill
PER_SAMPLE = 300  # measured particles per sample
IMAGE_AT_H, IMAGE_PARTICLES, IMAGE_SHAPE, UM_PER_PX = 2.0, 60, (560, 760), 1.5


def sample_name(t_h: float) -> str:
    """File name of the particle table at ``t_h`` (``lab-300rpm-0p5h.csv``)."""
    return f"lab-300rpm-{format(t_h, 'g').replace('.', 'p')}h.csv"


def main() -> None:
    import tifffile

    from bmctl import io
    from bmctl.config import load_card, with_factors
    from bmctl.measure.render import render_micrograph
    from bmctl.measure.sampler import micrograph_sample
    from bmctl.measure.tables import write_table
    from bmctl.plant.plant import Plant

    g_plant, g_sample, g_image = (np.random.default_rng(s) for s in np.random.SeedSequence(SEED).spawn(3))
    card = with_factors(load_card(CARD), GAMMA_MULT, DELTA_MULT)
    plant = Plant(card, g_plant, PARTICLES)
    (OUT / "samples").mkdir(exist_ok=True)
    t, readings = 0.0, []
    for t_h in TIMES_H:
        plant.advance(RPM, t_h - t)
        t = t_h
        table = micrograph_sample(plant.s * 1e6, plant.r, PER_SAMPLE, g_sample)
        write_table(OUT / "samples" / sample_name(t_h), table)
        readings.append((t_h, round(float(plant.temperature_c), 1)))
        if t_h == IMAGE_AT_H:
            pick = g_image.choice(plant.s.size, IMAGE_PARTICLES, replace=False)
            m = render_micrograph(g_image, shape=IMAGE_SHAPE, s_px=plant.s[pick] * 1e6 / UM_PER_PX,
                                  r=plant.r[pick], um_per_px=UM_PER_PX)
            img = np.clip(np.round(m.image * 255), 0, 255).astype(np.uint8)
            tmp = OUT / ".micrograph-2h.tif.tmp"
            tifffile.imwrite(tmp, img, imagej=True, resolution=(1 / UM_PER_PX, 1 / UM_PER_PX),
                             metadata={"unit": "micron"}, compression="zlib")
            tmp.replace(OUT / "micrograph-2h.tif")
    io.write_csv(OUT / "readings.csv", ["t_h", "temperature_c"], readings)
    print(f"wrote {len(TIMES_H)} tables, readings.csv and micrograph-2h.tif under {OUT}")


if __name__ == "__main__":
    main()
