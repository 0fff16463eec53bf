"""The moment model of a card file, with its card-derived constants cached on disk (campaigns, trials, design).

:func:`bmctl.moments.model.make_moment_model` derives the card's constants and the default
threshold laws from a seeded Monte Carlo over 400 000 impacts
(:func:`bmctl.moments.physics.impact_factors`, ~1 s CPU), once per process. They are a
deterministic function of the card, the identified coefficients and the code, so a campaign
stores them as plain numbers (JSON, never code) in bmctl's own cache folder
(:func:`bmctl.control.cache.cache_dir`), keyed by a SHA-256 of the card bytes, the
coefficient file's bytes and the source of the modules that compute them. A missing,
unreadable or foreign entry is rebuilt; ``BMCTL_MPC_COMPILE=0`` turns the cache off; nothing from the campaign folder is loaded as a cache.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

#: modules whose code determines the constants and default coefficients (part of the key)
SOURCES = ("moments/physics.py", "moments/coeffs.py", "moments/model.py", "physics/impacts.py",
           "physics/kinematics.py", "physics/thermal.py", "physics/constants.py", "config.py", "cards.py")
FORMAT = 1


def _key(card_path: Path, coeffs_path: Path | None) -> str:
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256(f"bmctl-moment-model-{FORMAT}-numpy-{np.__version__}\0".encode())
    from ..io import read_input_bytes

    for p in [card_path, coeffs_path] + [root / s for s in SOURCES]:
        h.update(str(p.name if p is not None else "-").encode() + b"\0")
        h.update(read_input_bytes(p) if p is not None and p.exists() else b"-")  # a regular file (no FIFO)
        h.update(b"\0")
    return h.hexdigest()[:24]


def _entry(card_path: Path, coeffs_path: Path | None) -> Path | None:
    from ..control import cache

    if os.environ.get(cache.ENV_SWITCH, "1") == "0":  # no caches at all (tests, debugging)
        return None
    d = cache.cache_dir()
    return None if d is None else d / f"model-{_key(card_path, coeffs_path)}.json"


def _restore(card, doc: dict, coeffs_file: Path | None):
    from ..moments.model import MomentModel
    from ..moments.physics import Constants

    c = dict(doc["const"])
    for k in ("round_nodes", "contact_nodes"):
        c[k] = tuple(tuple(float(v) for v in node) for node in c[k])
    m = MomentModel.__new__(MomentModel)  # MomentModel.__init__ without constants(card): the cached ones
    m.card = card
    m.const = Constants(**c)
    m.coeffs = {k: float(v) for k, v in doc["coeffs"].items()}
    m.coeffs_source = str(coeffs_file) if coeffs_file is not None else str(doc["coeffs_source"])
    m._ca_steps, m._ca_sims = {}, {}
    return m


def moment_model(card_path) -> object:
    """:func:`~bmctl.moments.model.make_moment_model` of ``card_path`` (with its ``.moments.toml``),
    its constants and coefficients from bmctl's cache when they were derived before.

    Parameters
    ----------
    card_path : path-like
        The campaign's copy of the model card.

    Returns
    -------
    MomentModel
    """
    from ..config import load_card
    from ..moments.coeffs import coeffs_path
    from ..moments.model import make_moment_model

    card_path = Path(card_path)
    cp = coeffs_path(card_path)
    cp = cp if cp.exists() else None
    try:
        entry = _entry(card_path, cp) if card_path.is_file() else None
    except OSError:  # unreadable card: make_moment_model says so in one line
        entry = None
    if entry is not None and entry.is_file():
        try:
            doc = json.loads(entry.read_text(encoding="utf-8"))
            if doc.get("format") == FORMAT:
                return _restore(load_card(card_path), doc, cp)
        except (OSError, ValueError, KeyError, TypeError):
            pass
    model = make_moment_model(card_path)
    if entry is not None:
        doc = {"format": FORMAT, "const": model.const.as_dict(), "coeffs": model.coeffs,
               "coeffs_source": model.coeffs_source}
        try:
            fd, tmp = tempfile.mkstemp(prefix=".model-", suffix=".json", dir=entry.parent)
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(doc, f)
            os.replace(tmp, entry)
        except OSError:
            pass
    return model
