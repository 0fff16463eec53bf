"""Where the shipped model cards (``models/``) and controller settings (``controllers/``) are.

A clone (``pip install -e .``) reads them from the repository beside the package; a wheel
(``pip install .``, ``pip install git+...``) carries copies inside the package, under
``bmctl/_shipped/`` (``setup.py`` maps them there). One function says where, for every part of
bmctl that reads a shipped default.

Examples
--------
>>> (shipped_dir("models") / "alni-1to1-300rpm-lab.toml").is_file()
True
>>> shipped_dir("scenarios-of-nobody") is None
True
"""

from __future__ import annotations

from pathlib import Path

#: the folder above the package: a clone's models/, controllers/ and scenarios/
REPOSITORY = Path(__file__).resolve().parents[1]
#: where a wheel carries the shipped folders (absent in a clone)
PACKAGED = Path(__file__).resolve().parent / "_shipped"
#: the folders a wheel carries (setup.py maps each into ``bmctl/_shipped/``)
FOLDERS = ("models", "controllers")


def shipped_dir(folder: str) -> Path | None:
    """The shipped ``folder`` (``"models"`` or ``"controllers"``): the copy a wheel carries, else
    the clone's (the folder above the package holds bmctl's ``pyproject.toml``: beside an installed
    package a folder of that name would be another package's), else ``None``.

    Parameters
    ----------
    folder : str
        ``"models"`` or ``"controllers"``.

    Returns
    -------
    pathlib.Path or None
    """
    if (PACKAGED / folder).is_dir():
        return PACKAGED / folder
    if (REPOSITORY / "pyproject.toml").is_file() and (REPOSITORY / folder).is_dir():
        return REPOSITORY / folder
    return None


def models_dir() -> Path:
    """The shipped model cards' folder (:func:`shipped_dir`; where a wheel would carry it when the
    installation has none, so that a path under it names no file rather than failing)."""
    return shipped_dir("models") or PACKAGED / "models"
