"""The moment model of a card, on coefficients identified for that card: the one loader every command uses.

A coefficient file (``<card>.moments.toml``, :mod:`bmctl.moments.coeffs`) records the fingerprint
of the card fields the model depends on (:func:`bmctl.cards.fingerprint_values`). :func:`for_card`
builds the model only when the file next to the card (or the one named) was identified for a card
with the same values; otherwise it refuses in one line that names the card, the differing fields and
the command that fixes it, or, when asked (``--identify``), identifies the card on the spot and
writes the file next to it. docs/moments.md, Sec. 6 and 9.

Examples
--------
>>> from bmctl.moments import for_card
>>> model = for_card("models/alni-1to1-300rpm-lab.toml")
>>> model.coeff_file.card_name
'alni-1to1-300rpm-lab'
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..errors import InputError
from ..naming import arg
from ..shipped import models_dir
from . import coeffs as cf

#: the shipped cards' folder (a clone's models/ or the copy a wheel carries): ``bmctl identify``
#: never writes over a file here unless asked (``--overwrite``)
SHIPPED_DIR = models_dir()


def is_shipped(path: str | Path) -> bool:
    """Whether ``path`` is an existing file in the shipped ``models/`` folder.

    Parameters
    ----------
    path : path-like

    Examples
    --------
    >>> from bmctl.shipped import models_dir
    >>> is_shipped(models_dir() / "alni-1to1-300rpm-lab.moments.toml"), is_shipped("/tmp/x.moments.toml")
    (True, False)
    """
    p = Path(path)
    try:
        return p.is_file() and p.resolve().parent == SHIPPED_DIR.resolve()
    except OSError:
        return False


@dataclass
class Status:
    """Whether a card has coefficients of its own (:func:`status`).

    Attributes
    ----------
    state : str
        ``"match"``, ``"mismatch"`` (identified for other card values), ``"unrecorded"`` (the file
        records no card fingerprint), ``"incomplete"`` (it records one but lacks coefficients, which
        the model would silently replace by its defaults: the file was edited or cut) or ``"missing"``.
    path : Path or None
        The coefficient file looked at.
    file : CoeffFile or None
        Its content (None when missing).
    diff : list of str
        The differing fields, ``"table.field <card> (coefficients: <file>)"``; for ``"incomplete"``, the
        missing coefficients.
    """

    state: str
    path: Path | None
    file: cf.CoeffFile | None = None
    diff: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return self.state == "match"

    def line(self) -> str:
        """One line for ``card show``: where the coefficients are and whether they are this card's."""
        if self.state == "missing":
            return f"none ({self.path} does not exist)"
        if self.state == "unrecorded":
            return f"{self.path}: records no card fingerprint (identified before fingerprints; re-identify)"
        if self.state == "incomplete":
            return f"{self.path}: lacks {len(self.diff)} coefficient(s) ({_names(self.diff)}); re-identify"
        if self.state == "mismatch":
            return (f"{self.path}: identified for other values of {len(self.diff)} field(s): "
                    + "; ".join(self.diff[:4]) + (" ..." if len(self.diff) > 4 else ""))
        return f"{self.path} (its card fingerprint matches this card)"


def status(card, card_path: str | Path | None = None, coeffs: str | Path | None = None) -> Status:
    """Compare a card with the coefficient file it would use.

    Parameters
    ----------
    card : ModelCard
    card_path : path-like, optional
        The card's file: the coefficients are looked for next to it (``<card>.moments.toml``).
    coeffs : path-like, optional
        A coefficient file to use instead.

    Returns
    -------
    Status
    """
    from ..cards import fingerprint_diff, fingerprint_values

    path = Path(coeffs) if coeffs is not None else (cf.coeffs_path(card_path) if card_path is not None else None)
    if path is None or not path.exists():
        return Status("missing", path)
    f = cf.read_file(path)
    if f.values is None:
        return Status("unrecorded", path, f)
    lacking = tuple(k for k in cf.NAMES if k not in f.coeffs)  # identify writes them all (since fingerprints)
    if lacking:
        return Status("incomplete", path, f, lacking)
    diff = fingerprint_diff(fingerprint_values(card), f.values)
    return Status("mismatch" if diff else "match", path, f, tuple(diff))


def refusal(where: str, st: Status, fix: str) -> InputError:
    """The one-line error for a card without coefficients of its own.

    Parameters
    ----------
    where : str
        The card (its file).
    st : Status
        From :func:`status`.
    fix : str
        The command that fixes it.
    """
    if st.state == "missing":
        what = f"none identified for this card ({st.path} does not exist)" if st.path else "none given"
    elif st.state == "unrecorded":
        what = f"{st.path} records no card fingerprint, so it may belong to another card"
    elif st.state == "incomplete":
        what = (f"{st.path} lacks {len(st.diff)} of the {len(cf.NAMES)} coefficients ({_names(st.diff)}), "
                "so the model would run on defaults there: the file was edited or cut")
    else:
        other = f" {st.file.card_name!r}" if st.file and st.file.card_name else ""
        what = (f"{st.path} was identified for card{other} with other values of {len(st.diff)} field(s): "
                + "; ".join(st.diff[:3]) + (f"; and {len(st.diff) - 3} more" if len(st.diff) > 3 else ""))
    return InputError(f"{where}: moment coefficients: {what}; fix: {fix}")


def check_own(card, card_path: str | Path, where: str | None = None) -> Status:
    """The :func:`status` of the coefficient file next to ``card_path``, or :func:`refusal` when it
    exists but is not this card's (other values, no fingerprint, coefficients missing): the check of
    :func:`for_card`, for :func:`bmctl.moments.make_moment_model`.

    Parameters
    ----------
    card : ModelCard
        The card read from ``card_path``.
    card_path : path-like
        The card's file.
    where : str, optional
        The caller, named in the fix.

    Returns
    -------
    Status
        ``"match"`` or ``"missing"``.
    """
    st = status(card, card_path)
    if st.state not in ("match", "missing"):
        also = f", or pass coeffs= to {where}" if where else ""
        raise refusal(str(card_path), st, f"bmctl identify {card_path} (about a minute){also}")
    return st


def _names(names, n: int = 3) -> str:
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


def for_card(card, *, identify: bool = False, progress: Callable[[str], None] | None = None,
             coeffs: str | Path | None = None, client=None):
    """The moment model of ``card`` on coefficients identified for it.

    Parameters
    ----------
    card : path-like or ModelCard
        The card file (its coefficients are ``<card>.moments.toml`` next to it), or a card with
        ``coeffs`` naming the file.
    identify : bool, optional
        When the coefficients are missing or belong to other card values: identify the card now
        (:func:`identify_card`, about a minute, progress through ``progress``) and write the file next
        to the card, instead of refusing.
    progress : callable, optional
        Called with progress lines of an identification (default: printed on stderr).
    coeffs : path-like, optional
        Use this coefficient file instead of the one next to the card.
    client : distributed.Client, optional
        Dask engine for the plant runs of an identification.

    Returns
    -------
    MomentModel
        With ``coeff_file`` (:class:`~bmctl.moments.coeffs.CoeffFile`): the held-out error and the
        operating window of its coefficients.

    Raises
    ------
    InputError
        Missing or foreign coefficients without ``identify``: one line naming the card, the
        differing fields and the command that fixes it.
    """
    from ..config import ModelCard, load_card

    if isinstance(card, ModelCard):
        card_obj, card_path = card, None
        where = f"card {card.card.name}"
    else:
        card_path = Path(card)
        card_obj = load_card(card_path)
        where = str(card_path)
    st = status(card_obj, card_path, coeffs)
    if not st.ok:
        if not identify or card_path is None:
            fix = (f"bmctl identify {card_path} (about a minute), or add {arg('identify=True')}" if card_path is not None
                   else "identify the card (bmctl identify CARD.toml)")
            raise refusal(where, st, fix)
        out = Path(coeffs) if coeffs is not None else cf.coeffs_path(card_path)
        if is_shipped(out):
            raise InputError(f"{out}: is a shipped coefficient file of another card version; copy the card out of "
                             f"models/ and identify the copy, or run bmctl identify {card_path} --overwrite")
        log = progress or _stderr
        log(f"{where}: {'no' if st.state == 'missing' else 'foreign'} moment coefficients; identifying the card "
            f"(writes {out})")
        identify_card(card_obj, card_path, out, log=log, client=client)
        st = status(card_obj, card_path, coeffs)
    return _model(card_obj, card_path, st)


def _model(card, card_path, st: Status):
    from .model import make_moment_model
    from .modelcache import moment_model

    if card_path is not None and st.path == cf.coeffs_path(card_path):
        model = moment_model(card_path)  # constants from bmctl's cache when derived before
    else:
        model = make_moment_model(card, st.path)
    model.coeff_file = st.file
    return model


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def identify_card(card, card_path: str | Path | None, out: str | Path, **kw):
    """Identify ``card`` (:func:`identification`) and write its coefficient file to ``out`` (atomic).

    Parameters
    ----------
    card : ModelCard
    card_path : path-like or None
        The card's file (named in the recorded command).
    out : path-like
        The coefficient file to write.
    **kw
        Passed to :func:`identification`.

    Returns
    -------
    Identification
    """
    from ..io import write_text

    res = identification(card, card_path, replaces=out, **kw)
    write_text(out, res.toml)
    return res


def identification_text(card, card_path: str | Path | None, **kw) -> str:
    """The coefficient file's text of :func:`identification` (for a caller that writes it with other files).

    Parameters
    ----------
    card : ModelCard
    card_path : path-like or None
        Where the card is (or will be) written: named in the recorded command.
    **kw
        Passed to :func:`identification`.
    """
    return identification(card, card_path, **kw).toml


def identification(card, card_path: str | Path | None, *, seed: int = 0, log=None, client=None,
                   workers: int | None = None, scheduler: str | None = None, command: str | None = None,
                   start: str | Path = "nearest", replaces: str | Path | None = None, **kw):
    """:func:`bmctl.moments.identify.identify` of ``card``, on a Dask engine of its own unless given one.

    Parameters
    ----------
    card : ModelCard
    card_path : path-like or None
        The card's file (named in the recorded command; its folder is searched for identified cards).
    seed : int, optional
        Seed of the plant ensembles and the design.
    log : callable, optional
        Progress lines.
    client : distributed.Client, optional
        A Dask engine to use; else one is started for the plant runs (``workers``, ``scheduler``) and
        closed after.
    workers : int, optional
        Local Dask worker processes (default: the machine's CPUs; 0 or 1: serial).
    scheduler : str, optional
        A running Dask scheduler.
    command : str, optional
        The command line recorded in ``[identification]`` (default ``bmctl identify <card> --seed N``).
    start : str or path-like, optional
        Where the fit starts: ``"nearest"`` (from the nearest identified card in the card's folder or
        the shipped ``models/``, :func:`bmctl.moments.identify.warm_start`, and from the built-in
        defaults, keeping the lower cost), ``"defaults"`` (the built-in defaults only) or a coefficient
        file (only it).
    replaces : path-like, optional
        The coefficient file this identification will write (default: ``<card>.moments.toml`` next to
        ``card_path``): never a ``"nearest"`` start, so a repeated identification with the same seed starts
        where the first did and gives the same coefficients.
    **kw
        Passed to :func:`bmctl.moments.identify.identify` (``quick``, ``particles``, ``seeds``, ...).

    Returns
    -------
    Identification
    """
    from ..parallel import auto_workers, client_for, close_client
    from . import identify as ident

    command = command or f"bmctl identify {card_path if card_path is not None else card.card.name} --seed {seed}"
    if str(start) == "defaults":
        first, label = None, ""
    elif str(start) == "nearest":
        where = [Path(card_path).parent] if card_path is not None else []
        if replaces is None and card_path is not None:
            replaces = cf.coeffs_path(card_path)
        mine = Path(replaces).resolve() if replaces is not None else None
        first, label = ident.warm_start(card, [c for c in ident.identified_candidates(*where)
                                               if mine is None or Path(c.path).resolve() != mine])
    else:
        first, label = ident.warm_start(card, [cf.read_file(start)])
        if not cf.read_file(start).values:
            raise InputError(f"{arg('start')}: {start}: records no card fingerprint; give an identified file")
    own = client is None
    if own:
        quick = kw.get("quick", False)
        seeds = kw.get("seeds") or (1 if quick else ident.DEFAULT_SEEDS)
        runs, cpu_s = ident.plant_work(card, ident.design(card, seed, quick, kw.get("random_schedules")), seeds,
                                       kw.get("particles") or ident.default_particles(quick))
        client = client_for(scheduler, auto_workers(runs, cpu_s, workers, scheduler))
    try:
        return ident.identify(card, seed, source=str(card_path or card.card.name), command=command, log=log,
                              client=client, start=first, start_label=label, both_starts=str(start) == "nearest",
                              **kw)
    finally:
        if own:
            close_client(client)
