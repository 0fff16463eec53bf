"""Micrograph measurement: segmentation, particle tables, synthetic renderer, plant sampler.

The user-facing unit is the micrometre (``_um`` names). Size ``s = 2 sqrt(A / pi)``
(paper eqn 1) and aspect ratio ``r = 1 - pi s / L`` (eqn 3) come from each particle's
section area A and measured boundary length L. See ``docs/measurement.md``.
"""

from .render import Micrograph, render_micrograph
from .sampler import micrograph_sample
from .segment import Segmentation, load_image, measure_image, measure_labels
from .segment import segment as segment_image  # ``bmctl.measure.segment`` stays the module
from .tables import ParticleTable, read_table, write_table

__all__ = [
    "Micrograph",
    "ParticleTable",
    "Segmentation",
    "load_image",
    "measure_image",
    "measure_labels",
    "micrograph_sample",
    "read_table",
    "render_micrograph",
    "segment_image",
    "write_table",
]
