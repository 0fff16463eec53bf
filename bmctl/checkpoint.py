"""Checkpoints as plain data: arrays, numbers and strings, never objects.

A state is a nested dict (what each object's ``get_state`` returns) of numbers, strings,
``None``, lists, dicts and numpy arrays. :func:`save_state` writes it to one ``.npz`` file:
every array under its path (``"plant/s"``), the rest as one JSON document (``"__json__"``)
in which an array is a reference ``{"__array__": "plant/s"}``. :func:`load_state` reads it
with ``allow_pickle=False``: a checkpoint from an untrusted folder cannot run code, and a
truncated or foreign file is an :class:`~bmctl.errors.InputError` naming the file.

Floats round-trip exactly (JSON writes ``repr``); tuples come back as lists.

Examples
--------
>>> import numpy as np, tempfile, pathlib
>>> state = {"plant": {"s": np.arange(3.0), "t_s": 1.5}, "k": 2, "rng": {"state": 2**100}}
>>> p = pathlib.Path(tempfile.mkdtemp()) / "checkpoint.npz"
>>> save_state(p, state)
>>> back = load_state(p)
>>> back["plant"]["s"].tolist(), back["plant"]["t_s"], back["k"], back["rng"]["state"] == 2**100
([0.0, 1.0, 2.0], 1.5, 2, True)
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from . import io
from .errors import InputError

JSON_KEY = "__json__"
ARRAY_TAG = "__array__"


def _split(value, path: str, arrays: dict):
    """The JSON-able image of ``value``; its arrays go to ``arrays`` under their path."""
    if isinstance(value, np.ndarray):
        arrays[path] = value
        return {ARRAY_TAG: path}
    if isinstance(value, dict):
        return {str(k): _split(v, f"{path}/{k}", arrays) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_split(v, f"{path}/{i}", arrays) for i, v in enumerate(value)]
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"checkpoint: {path}: {type(value).__name__} is not plain data")


def _join(value, arrays):
    if isinstance(value, dict):
        if set(value) == {ARRAY_TAG}:
            return arrays[value[ARRAY_TAG]]
        return {k: _join(v, arrays) for k, v in value.items()}
    if isinstance(value, list):
        return [_join(v, arrays) for v in value]
    return value


def save_state(path: str | os.PathLike, state: dict) -> None:
    """Write ``state`` (plain data, see the module) to ``path`` atomically."""
    arrays: dict[str, np.ndarray] = {}
    doc = _split(state, "", arrays)
    text = json.dumps(doc, allow_nan=True)
    with io.atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **{JSON_KEY: np.array(text)}, **arrays)


def load_state(path: str | os.PathLike) -> dict:
    """Read a state written by :func:`save_state`; anything else is an InputError naming ``path``.

    The file is read as a regular file of bounded size (:func:`bmctl.io.read_input_bytes`: a
    FIFO or device in its place is refused, not waited on), its arrays through
    :func:`bmctl.io.load_npz` (headers checked before allocation, no object arrays) and its
    JSON part through :func:`bmctl.io.loads_json` (bounded depth).
    """
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        raise InputError(f"{path}: not found")
    arrays = io.load_npz(path, str(path))
    if JSON_KEY not in arrays or arrays[JSON_KEY].dtype.kind != "U" or arrays[JSON_KEY].ndim != 0:
        raise InputError(f"{path}: not a bmctl checkpoint (no JSON part)")
    doc = io.loads_json(str(arrays.pop(JSON_KEY)), f"{path}: {JSON_KEY}")
    try:
        return _join(doc, arrays)
    except (KeyError, TypeError):
        raise InputError(f"{path}: not a bmctl checkpoint (an array reference without its array)") from None


def rng_state(rng: np.random.Generator) -> dict:
    """A generator's bit-generator state as plain data (JSON-able)."""
    return rng.bit_generator.state


def set_rng_state(rng: np.random.Generator, state: dict) -> None:
    """Restore a state from :func:`rng_state` (the bit generator's kind must match)."""
    rng.bit_generator.state = state
