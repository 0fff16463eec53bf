"""Results files: the measured numbers that README.md and docs/ quote.

Every study or benchmark in ``benchmarks/`` writes its numbers with :func:`write_results`
to ``results/<name>.json`` at the repository root. Each file holds the values plus what is
needed to reproduce them: the bmctl version, the command that wrote it, the settings and
the UTC time. Docs tie a number to its file with invisible markers
(``<!--r:FILE:KEY-->VALUE<!--/r-->``), and ``tests/test_results_docs.py`` checks that every
marked number equals the file's value rounded to the displayed decimals.

``python benchmarks/regenerate.py`` re-runs every registered study and rewrites its file.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from pathlib import Path
from typing import Any, Mapping

from . import __version__
from .io import write_text

#: environment variable that moves the results folder (tests and dry runs)
RESULTS_DIR_ENV = "BMCTL_RESULTS_DIR"

_RESERVED = ("bmctl_version", "command", "settings", "created_utc")


def results_dir() -> Path:
    """The results folder: ``$BMCTL_RESULTS_DIR`` if set, else ``results/`` at the repository root.

    Examples
    --------
    >>> results_dir().name
    'results'
    """
    env = os.environ.get(RESULTS_DIR_ENV)
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1] / "results"


def _plain(obj: Any) -> Any:
    """JSON-ready copy of ``obj``: numpy scalars and arrays become numbers and lists,
    tuples become lists, non-finite floats become ``None`` (JSON has no NaN)."""
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):  # numpy scalar / array
        return _plain(obj.tolist())
    if isinstance(obj, bool) or obj is None or isinstance(obj, (int, str)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"results: cannot store a {type(obj).__name__} in JSON")


def results_path(name: str) -> Path:
    """Path of results file ``name`` (``.json`` added when missing).

    Parameters
    ----------
    name : str
        File stem such as ``"fidelity_table"``; a plain name, never a path.

    Examples
    --------
    >>> results_path("fidelity_table").name
    'fidelity_table.json'
    """
    if not name or "/" in name or "\\" in name or name.startswith("."):
        raise ValueError(f"results: {name!r} is not a plain file name")
    return results_dir() / (name if name.endswith(".json") else name + ".json")


def write_results(name: str, values: Mapping[str, Any], *, settings: Mapping[str, Any],
                  command: str) -> Path:
    """Write ``results/<name>.json`` atomically and return its path.

    Parameters
    ----------
    name : str
        File stem (``"control_study"`` writes ``results/control_study.json``).
    values : mapping
        The measured numbers (nested dicts and lists of numbers, strings, booleans; numpy
        scalars and arrays are converted). Keys ``bmctl_version``, ``command``, ``settings``
        and ``created_utc`` are reserved.
    settings : mapping
        The inputs that produced the numbers (seeds, hours, counts, card names ...).
    command : str
        The shell command that regenerates this file, as a user would type it.

    Returns
    -------
    pathlib.Path
        The file written.

    Examples
    --------
    >>> import os, tempfile
    >>> os.environ["BMCTL_RESULTS_DIR"] = tempfile.mkdtemp()
    >>> p = write_results("demo", {"error_pct": 1.25}, settings={"seed": 0},
    ...                   command="python benchmarks/demo.py")
    >>> load_results("demo")["error_pct"]
    1.25
    >>> del os.environ["BMCTL_RESULTS_DIR"]
    """
    clash = [k for k in _RESERVED if k in values]
    if clash:
        raise ValueError(f"results: {name}: reserved key(s) in values: {', '.join(clash)}")
    record = {
        "bmctl_version": __version__,
        "command": command,
        "settings": _plain(settings),
        "created_utc": _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat(),
    }
    record.update(_plain(values))
    path = results_path(name)
    write_text(path, json.dumps(record, indent=1, sort_keys=False, allow_nan=False) + "\n")
    return path


def load_results(name: str) -> dict:
    """Read ``results/<name>.json``.

    Parameters
    ----------
    name : str
        File stem (or file name ending in ``.json``).

    Returns
    -------
    dict
        The whole record: values plus ``bmctl_version``, ``command``, ``settings``, ``created_utc``.
    """
    return json.loads(results_path(name).read_text(encoding="utf-8"))


def lookup(record: Any, key: str) -> Any:
    """Follow a dotted ``key`` into a loaded record; integer parts index lists.

    Parameters
    ----------
    record : dict or list
        A loaded results record.
    key : str
        Dotted path such as ``"summary.median_error_pct"`` or ``"rows.2.d50_um"``.

    Raises
    ------
    KeyError
        When a part of the path is absent.

    Examples
    --------
    >>> lookup({"rows": [{"a": 1.5}]}, "rows.0.a")
    1.5
    """
    obj = record
    for part in key.split("."):
        if isinstance(obj, list):
            try:
                obj = obj[int(part)]
            except (ValueError, IndexError):
                raise KeyError(key) from None
        elif isinstance(obj, dict) and part in obj:
            obj = obj[part]
        else:
            raise KeyError(key)
    return obj


def marked(name: str, key: str, value: float, fmt: str = "{:.3g}") -> str:
    """``value`` formatted with ``fmt`` and wrapped in a doc marker pointing at ``name``'s ``key``.

    Studies print their Markdown tables through this, so a table pasted into a doc carries
    its markers (``tests/test_results_docs.py`` then checks each cell against the file).

    Parameters
    ----------
    name : str
        Results file stem (``"control_study"``).
    key : str
        Dotted path of the value inside the file.
    value : float
        The value (as stored in the file).
    fmt : str, optional
        Format for the displayed number.

    Examples
    --------
    >>> marked("control_study", "mpc.mean_pct", 7.614, "{:.2f}")
    '<!--r:control_study.json:mpc.mean_pct-->7.61<!--/r-->'
    """
    stem = name[:-5] if name.endswith(".json") else name
    shown = fmt.format(value).replace("-", "−") if value is not None else "n/a"
    return f"<!--r:{stem}.json:{key}-->{shown}<!--/r-->"
