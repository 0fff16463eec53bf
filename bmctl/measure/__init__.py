"""Micrograph measurement: segmentation, particle tables, synthetic renderer, plant sampler.

The user-facing unit is the micrometre (``_um`` names). Size ``s = 2 sqrt(A / pi)``
(paper eqn 1) and aspect ratio ``r = 1 - pi s / L`` (eqn 3) come from each particle's
section area A and measured boundary length L. See ``docs/measurement.md``.

The names below load their module on first use (PEP 562): a command that needs only the particle
tables or the path helpers (``bmctl campaign status``, ``log``, ``decide``) does not import
scikit-image and the renderer.
"""

from __future__ import annotations

import importlib

#: name -> (submodule, attribute); ``segment_image`` is :func:`bmctl.measure.segment.segment`
#: (``bmctl.measure.segment`` stays the module)
_LAZY = {
    "Micrograph": ("render", "Micrograph"),
    "render_micrograph": ("render", "render_micrograph"),
    "micrograph_sample": ("sampler", "micrograph_sample"),
    "Segmentation": ("segment", "Segmentation"),
    "load_image": ("segment", "load_image"),
    "measure_image": ("segment", "measure_image"),
    "measure_labels": ("segment", "measure_labels"),
    "segment_image": ("segment", "segment"),
    "ParticleTable": ("tables", "ParticleTable"),
    "read_table": ("tables", "read_table"),
    "write_table": ("tables", "write_table"),
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(f".{module}", __name__), attr)
        globals()[name] = value  # later lookups skip this function
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
