"""The whole calibration: histories in, calibrated card, calibration.json and figures out.

Shared by ``bmctl calibrate`` and ``benchmarks/calibrate_accuracy.py``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..config import ModelCard
from ..io import name_part
from ..parallel import map_seeded
from .fit import Calibration, FitSettings, calibrate
from .history import History
from .simulate import simulate_task

MODEL_SAMPLE = 5000  # model particles per sample time kept for figures and distances


@dataclass
class CalibrationRun:
    """A finished calibration and where its outputs went."""

    calibration: Calibration
    start_info: dict
    model_samples: list  # per history: list of (s_um, r) per sample time
    distances: list[dict]
    paths: list[Path]
    wall_s: float
    removed: list[Path] = field(default_factory=list)  # figures of an earlier calibration in ``out``


def model_samples_at(cal: Calibration, card: ModelCard, histories: Sequence[History], settings: FitSettings,
                     seed: int, client=None) -> list:
    """Particles of the calibrated plant at each history's sample times (one run per history)."""
    from .fit import _Evaluator

    ev = _Evaluator(card, cal.names, histories, settings, None, client, None)
    tasks = [ev.task(cal.u, h, keep=MODEL_SAMPLE) for h in histories]
    seeds = np.random.SeedSequence(seed).spawn(3)[2].spawn(len(histories))
    return [o[1] for o in map_seeded(simulate_task, tasks, seeds, client)]


def run_calibration(card: ModelCard, card_path: str | Path, histories: Sequence[History], names: Sequence[str],
                    out: str | Path | None, seed: int = 0, settings: FitSettings | None = None, client=None,
                    moment_stage: bool = True, progress: Callable[[int], None] | None = None,
                    on_iteration: Callable[[dict], None] | None = None,
                    log: Callable[[str], None] | None = None) -> CalibrationRun:
    """Moment-model start, plant fit, final model run, outputs (when ``out`` is given).

    Parameters
    ----------
    card : ModelCard
        Starting card.
    card_path : path-like
        Its file (names the outputs; its moment coefficients serve the first stage).
    histories : sequence of History
    names : sequence of str
        Parameters to fit.
    out : path-like or None
        Output folder; None writes nothing.
    seed : int, optional
    settings : FitSettings, optional
    client : distributed.Client, optional
    moment_stage : bool, optional
        Start gamma and delta from the moment model's maximum likelihood (default True).
    progress, on_iteration : callable, optional
        Progress hooks (see :func:`bmctl.calibrate.fit.calibrate`).
    log : callable, optional
        Progress lines of the calibrated card's moment identification.

    Returns
    -------
    CalibrationRun
    """
    from . import outputs
    from .params import check_calibratable

    names = list(names)
    for n in names:  # before any work
        check_calibratable(card, n)
    t0 = time.perf_counter()
    s = settings or FitSettings()
    start_u, info = None, {}
    if moment_stage:
        from .moment_start import moment_start

        start_u, info = moment_start(card_path, histories, names)
    cal = calibrate(card, histories, names, seed=seed, settings=s, start_u=start_u, client=client,
                    progress=progress, on_iteration=on_iteration)
    kept = model_samples_at(cal, card, histories, s, seed, client)
    dist = outputs.sample_distances(histories, kept)
    paths: list[Path] = []
    wall = time.perf_counter() - t0
    if out is not None:
        out = Path(out)
        stem = Path(card_path).stem
        # fitted to a card text's limit: many or long history paths are named by folder, or counted
        note = outputs.calibration_note(seed, [h.path for h in histories], names)
        new = outputs.calibrated_card(card, names, cal.values, note)
        # the calibrated card's own moment coefficients (bmctl.moments.for_card refuses a card without them):
        # identified first, then card and coefficients written as one set
        from ..config import load_card
        from ..io import output_set, write_text
        from ..moments.coeffs import coeffs_path
        from ..moments.forcard import identification_text

        card_out = out / f"{stem}-calibrated.toml"
        text = identification_text(new, card_out, seed=seed, log=log, client=client,
                                   workers=0 if client is None else None)  # serial when the fit was
        meta = {"card": str(card_path), "seed": seed, "settings": s.model_dump(), "moment_stage": info,
                "wall_s": wall}
        figures = [out / f"histograms-{name_part(h.name)}.png" for h in histories]
        stale = stale_figures(out, figures, run_inputs(card_path, histories))
        with output_set():  # card, coefficients, calibration.json and figures: all of them or none
            write_text(card_out, outputs.card_toml(new, f"{new.card.name}: {note}\nSee calibration.json next to this "
                                                        "file; its moment coefficients are in the .moments.toml beside it."))
            write_text(coeffs_path(card_out), text)
            paths += [card_out, coeffs_path(card_out)]
            paths.append(outputs.write_json(out / "calibration.json", outputs.calibration_dict(cal, histories, dist, meta)))
            for h, k, fig in zip(histories, kept, figures):
                paths.append(outputs.plot_history(fig, h, k, f"{h.name}: measured vs calibrated {stem}"))
        for p in stale:  # the new calibration.json does not name them: they would pass for this run's
            p.unlink(missing_ok=True)
        load_card(card_out)  # the written card loads (as outputs.write_card checks)
    return CalibrationRun(cal, info, kept, dist, paths, wall, stale if out is not None else [])


def run_inputs(card_path: str | Path, histories: Sequence[History]) -> list[Path]:
    """The files a calibration reads: the card, its moment coefficients, each history, its schedule file
    and its samples (tables or images)."""
    from ..moments.coeffs import coeffs_path

    inputs = [Path(card_path), Path(coeffs_path(card_path))]
    for h in histories:
        inputs += [Path(h.path), *([Path(h.schedule)] if h.schedule else []), *(Path(s.source) for s in h.samples)]
    return inputs


def stale_figures(out: str | Path, figures: Sequence[str | Path] = (),
                  inputs: Sequence[str | Path] = ()) -> list[Path]:
    """The figures of an earlier calibration in ``out`` (:func:`earlier_figures`) that a new one removes:
    those it does not write again (``figures``), and never one of its ``inputs`` (the same file by
    :func:`bmctl.io.same_file`: a sample image that happens to bear such a name stays).

    Examples
    --------
    >>> import tempfile, json
    >>> d = Path(tempfile.mkdtemp())
    >>> record = {"histories": [{"name": "a"}, {"name": "b"}, {"name": "c"}]}
    >>> _ = (d / "calibration.json").write_text(json.dumps(record), encoding="utf-8")
    >>> for n in "abc":
    ...     _ = (d / f"histograms-{n}.png").write_bytes(b"")
    >>> [p.name for p in stale_figures(d, [d / "histograms-a.png"], [d / "." / "histograms-c.png"])]
    ['histograms-b.png']
    """
    from ..io import same_file

    out = Path(out)
    return [p for p in earlier_figures(out)
            if not any(same_file(p, f) for f in figures) and not any(same_file(p, i) for i in inputs)]


def earlier_figures(out: Path) -> list[Path]:
    """The histogram figures an earlier calibration wrote to ``out`` (those its ``calibration.json`` names
    that are still there); nothing when there is none or it cannot be read.

    Examples
    --------
    >>> import tempfile, json
    >>> d = Path(tempfile.mkdtemp())
    >>> _ = (d / "calibration.json").write_text(json.dumps({"histories": [{"name": "run 1"}, {"name": "b"}]}), encoding="utf-8")
    >>> _ = (d / "histograms-run_1.png").write_bytes(b"")
    >>> [p.name for p in earlier_figures(d)]
    ['histograms-run_1.png']
    """
    import json

    try:
        hist = json.loads((Path(out) / "calibration.json").read_text(encoding="utf-8")).get("histories", [])
        names = [str(h["name"]) for h in hist]
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return []
    figs = [Path(out) / f"histograms-{name_part(n)}.png" for n in names]
    return [p for p in dict.fromkeys(figs) if p.is_file()]
