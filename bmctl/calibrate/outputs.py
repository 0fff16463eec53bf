"""Outputs of a calibration: the calibrated card (TOML), calibration.json, histogram figures."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from .. import io
from ..config import TEXT_MAX_CHARS, ModelCard, load_card
from .fit import Calibration
from .history import History
from .params import set_params

IRREGULARITY_LABEL = "irregularity r = 1 − πs/L"


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return io.toml_string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def card_toml(card: ModelCard, header: str = "") -> str:
    """A model card as TOML text (sections and keys as ``bmctl.config.load_card`` reads them)."""
    lines = [f"# {ln}" for ln in header.splitlines()] + ([""] if header else [])
    for sec, body in card.model_dump().items():
        lines.append(f"[{sec}]")
        for k, v in body.items():
            if v is not None:
                lines.append(f"{k} = {_toml_value(v)}")
        lines.append("")
    return "\n".join(lines)


CALIBRATED_SUFFIX = "-calibrated"
ELLIPSIS = "..."


def fit_text(text: str, limit: int = TEXT_MAX_CHARS) -> str:
    """``text``, or its start cut to ``limit`` characters with an ellipsis at the end.

    Examples
    --------
    >>> fit_text("abcdef", 5)
    'ab...'
    >>> fit_text("abc", 5)
    'abc'
    """
    return text if len(text) <= limit else text[:max(limit - len(ELLIPSIS), 0)] + ELLIPSIS


def calibrated_name(name: str, limit: int = TEXT_MAX_CHARS) -> str:
    """``<name>-calibrated`` (``name`` as it is when it ends so), the name cut with an ellipsis before
    the suffix where the whole would pass ``limit`` characters (a card text field's limit).

    Examples
    --------
    >>> calibrated_name("lab")
    'lab-calibrated'
    >>> calibrated_name("lab-calibrated")
    'lab-calibrated'
    >>> calibrated_name("abcdefghij", 16)
    'ab...-calibrated'
    """
    if name.endswith(CALIBRATED_SUFFIX) and len(name) <= limit:
        return name
    if len(name) + len(CALIBRATED_SUFFIX) <= limit:
        return name + CALIBRATED_SUFFIX
    return fit_text(name, limit - len(CALIBRATED_SUFFIX)) + CALIBRATED_SUFFIX


def calibration_note(seed: int, paths: Sequence[str], names: Sequence[str], limit: int = TEXT_MAX_CHARS) -> str:
    """The calibrated card's ``card.sources`` entry of ``bmctl calibrate``: seed, history files, parameters.

    Every path is named while the note fits ``limit`` characters (a card text field's limit);
    otherwise the histories' common folder once and as many file names as fit, ``and N more``
    (all of them are in calibration.json), down to the number of histories alone.

    Examples
    --------
    >>> calibration_note(1, ["a/h1.toml", "a/h2.toml"], ["gamma", "delta"])
    'calibrated by bmctl calibrate (seed 1) from a/h1.toml, a/h2.toml: gamma, delta'
    >>> note = calibration_note(1, [f"notebook/run-{i}.toml" for i in range(1, 13)], ["gamma"], 130)
    >>> note[44:]
    '12 histories in notebook (run-1.toml, and 11 more, in calibration.json): gamma'
    """
    paths = [str(p) for p in paths]
    head, tail = f"calibrated by bmctl calibrate (seed {seed}) from ", f": {', '.join(names)}"
    note = head + ", ".join(paths) + tail
    if len(note) <= limit:
        return note
    n = len(paths)
    what = f"{n} histor{'y' if n == 1 else 'ies'}"
    try:
        folder = os.path.commonpath([os.path.dirname(p) for p in paths])
    except ValueError:  # absolute and relative paths mixed, or none
        folder = ""
    names_only = [os.path.basename(p) for p in paths]
    if folder:
        tries = [(f"{what} in {folder}", [os.path.relpath(p, folder) for p in paths]), (what, names_only)]
    else:
        tries = [(what, paths), (what, names_only)]
    for lead, items in tries:
        for k in range(n, 0, -1):
            listed = ", ".join(items[:k]) + (f", and {n - k} more, in calibration.json" if k < n else "")
            note = f"{head}{lead} ({listed}){tail}"
            if len(note) <= limit:
                return note
    return fit_text(f"{head}{what} (named in calibration.json){tail}", limit)


def calibrated_card(card: ModelCard, names: Sequence[str], values: Sequence[float], note: str) -> ModelCard:
    """``card`` with the named parameters set, renamed ``<name>-calibrated`` and the note in its sources.

    Name and note are fitted to a card text's limit (:data:`bmctl.config.TEXT_MAX_CHARS`): a name
    that would pass it is cut before the suffix with an ellipsis (:func:`calibrated_name`), a note cut
    at its end (:func:`fit_text`).
    """
    new = set_params(card, dict(zip(names, map(float, values))))
    d = new.model_dump()
    d["card"]["name"] = calibrated_name(d["card"]["name"])
    d["card"]["sources"] = list(d["card"]["sources"]) + [fit_text(note)]
    return type(card).model_validate(d)


def write_card(path: str | Path, card: ModelCard, header: str = "") -> Path:
    """Write ``card`` atomically and check that :func:`bmctl.config.load_card` accepts the file."""
    path = Path(path)
    io.write_text(path, card_toml(card, header))
    load_card(path)
    return path


def sample_distances(histories: Sequence[History], model_samples: Sequence[list]) -> list[dict]:
    """Energy distances (scipy) between measured and model samples: ln s and r, per sample time."""
    from scipy.stats import energy_distance

    out = []
    for h, kept in zip(histories, model_samples):
        for smp, (s_m, r_m) in zip(h.samples, kept):
            out.append({"history": h.name, "t_h": smp.t_h, "n_measured": int(smp.s_um.size),
                        "energy_distance_ln_s": float(energy_distance(np.log(smp.s_um), np.log(s_m))),
                        "energy_distance_r": float(energy_distance(smp.r, r_m))})
    return out


def calibration_dict(cal: Calibration, histories: Sequence[History], distances: list[dict], meta: dict) -> dict:
    """The content of calibration.json."""
    sd = np.sqrt(np.diag(cal.cov_u))
    params = {}
    for i, n in enumerate(cal.names):
        params[n] = {
            "card": float(cal.card_values[i]), "start": float(cal.start_values[i]),
            "estimate": float(cal.values[i]), "ratio_to_card": float(cal.values[i] / cal.card_values[i]),
            "interval90": [float(cal.lo90[i]), float(cal.hi90[i])],
            "sd_ln": float(sd[i]), "prior_sd_ln": cal.prior_sd,
            "identified": bool(cal.identified[i]), "why": cal.why[i],
        }
    corr = cal.cov_u / np.outer(sd, sd)
    lam = np.linalg.eigvalsh(cal.fisher)
    return {
        "method": "Gaussian synthetic likelihood of per-sample summaries (mean, std of ln s and r), "
                  "Gauss-Newton on common-random-number plant runs, estimate and 90 % intervals from a "
                  "scan of the posterior along its least-informed direction "
                  "(docs/calibration-from-data.md)",
        "parameters": params,
        "correlation_ln": corr.tolist(),
        "fisher_eigenvalues_ln": lam.tolist(),
        "fisher_rank": int(np.sum(lam > 1.0 / cal.prior_sd**2)),
        "chi2_at_optimum": cal.chi2, "n_summaries": cal.n_summaries,
        "sample_distances": distances,
        "converged": cal.converged, "stop_reason": cal.stop_reason, "plant_runs": cal.plant_runs, "start_choice": cal.start_choice,
        "iterations": cal.iterations, "ridge": cal.ridge,
        "histories": [{"name": h.name, "file": h.path, "times_h": h.times_h,
                       "particles_measured": [int(s.s_um.size) for s in h.samples]} for h in histories],
        **meta,
    }


def write_json(path: str | Path, data: dict) -> Path:
    """Write ``data`` as indented JSON, atomically."""
    io.write_text(path, json.dumps(data, indent=2) + "\n")
    return Path(path)


def _share(x: np.ndarray) -> np.ndarray:
    return np.full(x.size, 1.0 / max(x.size, 1))


def plot_history(path: str | Path, history: History, model_samples: list, title: str) -> Path:
    """Measured vs calibrated-model histograms at each sample time: size (log axis, µm) and r."""
    plt = io.pyplot()
    n = len(history.samples)
    fig, axes = plt.subplots(n, 2, figsize=(10, 2.4 * n + 0.6), squeeze=False)
    all_s = np.concatenate([s.s_um for s in history.samples] + [m[0] for m in model_samples])
    edges_s = np.geomspace(max(all_s.min(), 0.1) * 0.9, all_s.max() * 1.1, 40)
    edges_r = np.linspace(0, 1, 41)
    for k, (smp, (s_m, r_m)) in enumerate(zip(history.samples, model_samples)):
        a, b = axes[k]
        a.hist(smp.s_um, bins=edges_s, weights=_share(smp.s_um), alpha=0.5, color="C0",
               label=f"measured (n={smp.s_um.size})")
        a.hist(s_m, bins=edges_s, weights=_share(s_m), histtype="step", lw=1.5, color="C1", label="calibrated model")
        a.set_xscale("log")
        a.set_xlabel("size s (µm)")
        a.set_ylabel(f"t = {smp.t_h:g} h\nshare of particles")
        b.hist(smp.r, bins=edges_r, weights=_share(smp.r), alpha=0.5, color="C0")
        b.hist(r_m, bins=edges_r, weights=_share(r_m), histtype="step", lw=1.5, color="C1")
        b.set_xlabel(IRREGULARITY_LABEL)
        for ax in (a, b):
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    io.savefig(fig, path, dpi=110)
    return Path(path)
