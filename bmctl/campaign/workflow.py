"""A campaign: one batch on a real mill, run as a closed loop with a person as the mill.

Verbs (the Python API; ``bmctl campaign <verb>`` calls them)::

    init(DIR, model=CARD, controller=CONFIG, target={"d50_um": 45}, hours=12, temperature_max_c=60)
    log(DIR, rpm=300, hours=0.5, milling=0.75, temperature_c=41)     # what the mill ran
    sample(DIR, at_h=2.0, inputs=["a.tif", "b.csv"])                   # measured particles
    advise(DIR)      # estimate +- 90 %, next action, schedule to the batch end, end state, why
    decide(DIR, accept=True)  /  decide(DIR, accept=False, rpm=250)
    status(DIR);  report(DIR)

Each verb is one transaction on ``DIR/campaign.sqlite`` (:mod:`bmctl.campaign.db`).

The estimator's timeline
    The particle filter's belief is a function of the logged actions and observations only,
    not of the order in which they were entered. Its *nodes* are the action ends and the
    observation times up to the logged clock; at each node the filter is propagated over the
    logged inputs since the previous node (an action cut at a sample time inside it keeps its
    mill-then-rest order) and then updated with everything observed at that time (samples
    pooled, the vial-temperature reading with them) or, with nothing observed, read
    (which applies the deferred process noise; kept for the next sample with ``moment_noise_at =
    "sample"``). The state after every node is stored. A
    late observation (at or before the logged clock) removes the nodes from its time on and
    replays from the node before it, so the result equals the one had it arrived on time; an
    observation after the clock waits until the log reaches it. With on-time entries
    (log, then sample at its end) this is exactly the call sequence of ``bmctl trial``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import numbers
import os
import shutil
import stat
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, quote
from ..naming import arg, naming  # noqa: F401 - naming: re-exported (bmctl.campaign.workflow.naming)
from ..limits import HOURS_MIN
from . import db
from . import targets as tg
from .advice import _end_band, _measure, _schedule, _why, band_warning, sample_first, sampling, sampling_note
from .readings import estimate_warning, reading_warnings
from ..measure.names import path_text, refuse_repeats
from ..schedule import short_phase
from ..moments.forcard import for_card

# The campaign's particle filter (changes from FilterSettings' defaults; ``init`` records them in the
# campaign): offset-free in size, each particle carries a drift of ln s_mean per milling hour that the
# card's moment model misses (docs/estimation.md, "Offset-free size"); the moments take discrepancy
# noise for the milled hours and 2 % of the rest hours, so the hourly samples of a resting mill average
# out ("Rests"); and the filter learns the mill's impact energy per particle against the card's
# (``energy_mult``, log prior sd 0.25; "A third multiplier").
CAMPAIGN_FILTER = {"size_drift_prior_per_h": 0.1, "size_drift_walk_per_sqrt_h": 0.05, "rest_noise_fraction": 0.02,
                   "energy_prior_log_std": 0.25}
#: ``campaign init --no-energy-mult``: (gamma_mult, delta_mult) only
TWO_MULT_FILTER = {k: v for k, v in CAMPAIGN_FILTER.items() if k != "energy_prior_log_std"}

EPS_H = 1e-9
INPUTS = "inputs"
#: the longest batch a campaign may plan (h), as ``bmctl design --hours``
MAX_HOURS = 1000.0
#: the filter particles a campaign may run, as ``bmctl campaign init --particles``
PARTICLES_RANGE = (50, 200_000)


# --- helpers -------------------------------------------------------------------------------------
def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _finite(v, name: str, lo: float | None = None, hi: float | None = None, strict: bool = False) -> float:
    """A number argument of a verb, finite and within [lo, hi] (``strict``: > lo), else a one-line
    InputError naming ``name``. Text and flags are not numbers (``float`` reads ``"0.5"`` as 0.5 and
    ``True`` as 1)."""
    if isinstance(v, tg.NOT_NUMBERS):
        raise InputError(f"{name}: not a number ({quote(v)})")
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise InputError(f"{name}: not a number ({v!r})") from None
    if not math.isfinite(x):
        raise InputError(f"{name}: must be a finite number (got {v})")
    if lo is not None and (x < lo or (strict and x == lo)):
        raise InputError(f"{name}: must be {'>' if strict else '>='} {lo:g} (got {v})")
    if hi is not None and x > hi:
        raise InputError(f"{name}: must be <= {hi:g} (got {v})")
    return x


def _whole(v, name: str, lo: int, hi: int | None = None) -> int:
    """A whole-number argument of a verb within [lo, hi] (``hi`` None: no upper bound), as an int,
    else a one-line InputError naming ``name``. An integral float (``1000.0``) is its integer; text,
    flags and other fractions are refused (``int`` reads ``"3"`` as 3, ``True`` as 1, cuts ``50.7``)."""
    if isinstance(v, tg.NOT_NUMBERS):
        raise InputError(f"{name}: not a whole number ({quote(v)})")
    if isinstance(v, numbers.Integral):
        n = int(v)
    elif isinstance(v, numbers.Real) and math.isfinite(float(v)) and float(v).is_integer():
        n = int(v)
    else:
        raise InputError(f"{name}: not a whole number ({v!r})")
    span = "" if hi is None else f"; allowed: {lo} to {hi}"
    if n < lo:
        raise InputError(f"{name}: must be >= {lo} (got {v}){span}")
    if hi is not None and n > hi:
        raise InputError(f"{name}: must be <= {hi} (got {v}){span}")
    return n


def _check_meta(meta: dict, where: str) -> dict:
    """The campaign's meta data, each key of the type and range ``init`` writes (else an InputError)."""
    def bad(key, why):
        return InputError(f"{where}: meta {key!r}: {why} (damaged or edited)")

    for key in ("inputs", "target", "hours", "temperature_max_c", "seed", "particles", "controller_kind"):
        if key not in meta:
            raise bad(key, "missing")
    num = (int, float)
    h = meta["hours"]
    if not isinstance(h, num) or isinstance(h, bool) or not 0 < h <= MAX_HOURS:
        raise bad("hours", f"{h!r} is not a batch length in (0, {MAX_HOURS:g}] h")
    T = meta["temperature_max_c"]
    if T is not None and (not isinstance(T, num) or isinstance(T, bool) or not -50 <= T <= 400):
        raise bad("temperature_max_c", f"{T!r} is not a ceiling in [-50, 400] °C")
    if not isinstance(meta["seed"], int) or isinstance(meta["seed"], bool) or meta["seed"] < 0:
        raise bad("seed", f"{meta['seed']!r} is not a seed")
    n, (lo, hi) = meta["particles"], PARTICLES_RANGE
    if not isinstance(n, int) or isinstance(n, bool) or not lo <= n <= hi:
        raise bad("particles", f"{n!r} is not a particle count in [{lo}, {hi}]")
    tgt = meta["target"]
    if not isinstance(tgt, dict) or any(k not in tg.known_keys() or not isinstance(v, num) or isinstance(v, bool)
                                        or not (math.isfinite(v) and v > 0) for k, v in tgt.items()):
        raise bad("target", f"{tgt!r:.60} is not a target of known keys and positive values")
    inp = meta["inputs"]
    if not isinstance(inp, dict) or not {"card", "controller"} <= set(inp) or any(
            not isinstance(v, dict) or not isinstance(v.get("file"), str) or not isinstance(v.get("sha256"), str)
            for v in inp.values()):
        raise bad("inputs", "not the copied inputs' files and checksums")
    return meta


@dataclass
class Action:
    id: int
    t0_h: float
    t1_h: float
    hours: float
    rpm: float
    milling: float


# --- the campaign object ------------------------------------------------------------------------
class Campaign:
    """An open campaign: the database, and (built on first use) model, filter, controller, loop.

    A :class:`Campaign` kept across calls (the Python API, a simulated mill) reuses its
    compiled solvers; the CLI opens one per command.

    Parameters
    ----------
    folder : path-like
        The campaign folder (``campaign.sqlite`` and ``inputs/``).
    read_only : bool, optional
        For the verbs that only read (``status``, ``report``): a database the user may not
        write is opened read-only instead of refused.
    """

    def __init__(self, folder, _new: bool = False, read_only: bool = False):
        self.folder = Path(folder)
        self.con = db.open_db(self.folder, read_only=read_only)
        where = str(db.db_path(self.folder))
        try:
            db.check(self.con, where, prior=not _new)  # init opens it before writing the prior
            self.meta = _check_meta(db.get_meta(self.con, where), where)
            db.check_inputs(self.folder, self.meta["inputs"], where)
        except BaseException:
            self.con.close()
            raise
        self._loop = None

    def close(self) -> None:
        self.con.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --- objects ---------------------------------------------------------------------------
    def _input(self, key: str) -> Path:
        m = self.meta["inputs"][key]
        p = self.folder / m["file"]  # checked on open (db.check_inputs): a file under inputs/
        if not p.is_file() or _sha(p) != m["sha256"]:
            raise InputError(f"{p}: changed or missing since `campaign init` (the campaign runs on the copy "
                             f"taken then; sha256 {m['sha256'][:12]}...)")
        return p

    @property
    def loop(self):
        """The :class:`~bmctl.campaign.mill.CampaignLoop` (built once per object)."""
        if self._loop is None:
            self._loop = self._build()
        return self._loop

    def _build(self):
        from ..control import make_controller
        from ..control.config import load_controller, validate_controller
        from ..estimate import FilterSettings, ParticleFilter
        from ..loop import LoopConfig
        from .mill import CampaignLoop, OperatorMill, RecordedSensor

        m = self.meta
        card_path = self._input("card")
        if "moments" in m["inputs"]:
            self._input("moments")
        model = for_card(card_path)  # the card's own coefficients; constants cached on disk (modelcache)
        cfg_path = self._input("controller")
        cfg = load_controller(cfg_path)
        ceiling = m["temperature_max_c"]
        if ceiling is not None and "temperature" in type(cfg).model_fields:
            d = cfg.model_dump()
            d["temperature"]["ceiling_c"] = ceiling
            cfg = validate_controller(d, str(cfg_path))
        if ceiling is None and "temperature" in type(cfg).model_fields:
            ceiling = float(cfg.temperature.ceiling_c)
        controller = make_controller(cfg, model)
        direct = {k: v for k, v in m["target"].items() if k in tg.TARGET_KEYS}
        controller.set_target(direct, t_end_h=m["hours"])
        ss = np.random.SeedSequence(m["seed"])
        _, g_pf, g_sample = (np.random.default_rng(s) for s in ss.spawn(3))  # as bmctl trial: plant, filter, sampler
        pf = ParticleFilter(model, g_pf, self.filter_settings())
        lcfg = LoopConfig(hours=m["hours"], sample_every_h=m["hours"], temperature_reading=True, ceiling_c=ceiling)
        loop = CampaignLoop(OperatorMill(model.card.thermal.ambient_C), RecordedSensor(), pf, controller, g_sample, lcfg)
        loop.model = model
        return loop

    def filter_settings(self):
        """The campaign's particle-filter settings: ``init``'s record (a campaign written before it
        was recorded: :data:`CAMPAIGN_FILTER`) with the campaign's particle count."""
        changes = self.meta.get("estimator", CAMPAIGN_FILTER)
        if not isinstance(changes, dict):
            raise InputError(f"{self.folder}: meta 'estimator': not a table of filter settings (damaged or edited)")
        return _filter_settings(changes, self.meta["particles"], f"{self.folder}: meta 'estimator'")

    def ceiling_c(self) -> float | None:
        """The vial-temperature ceiling the campaign runs under (degC): ``init``'s, else the
        controller config's (None for a controller without one); builds nothing."""
        if self.meta["temperature_max_c"] is not None:
            return float(self.meta["temperature_max_c"])
        from ..control.config import load_controller

        cfg = load_controller(self._input("controller"))
        return float(cfg.temperature.ceiling_c) if "temperature" in type(cfg).model_fields else None

    def temperature_warnings(self, since_h: float | None = None) -> list[str]:
        """Warnings of the readings weighed in after ``since_h`` (all when None; each node's check,
        :mod:`bmctl.campaign.readings`) and of the latest estimate against the ceiling."""
        ceiling, sigma, ambient = self.ceiling_c(), self.filter_settings().sigma_temperature_c, self.ambient_c()
        out = []
        for t, est in self.estimates():
            if since_h is None or t > since_h + EPS_H:
                out += reading_warnings(est, ceiling, sigma, ambient)
        _, t_node, est = self.last_node()
        if t_node >= 0:
            out += estimate_warning(est, ceiling)
        return out

    def band_warnings(self, since_h: float | None = None) -> list[str]:
        """Warnings of the sample nodes after ``since_h`` (all when None) whose update left the filter
        nearly degenerate (:func:`bmctl.campaign.advice.band_warning`)."""
        rows = [(float(t), int(k), int(n)) for t, k, n in self.con.execute(
            "SELECT t_h, COUNT(*), SUM(n) FROM samples GROUP BY t_h")]
        node = _node_times([a.t1_h for a in self.actions()], [t for t, _, _ in rows])  # as the replay pools them
        pooled: dict[float, tuple[int, int]] = {}
        for t, k, n in rows:
            k0, n0 = pooled.get(node[t], (0, 0))
            pooled[node[t]] = (k0 + k, n0 + n)
        out = []
        for t, est in self.estimates():
            if t in pooled and (since_h is None or t > since_h + EPS_H):
                out += band_warning(est, *pooled[t], self.meta["particles"])
        return out

    def ambient_c(self) -> float:
        """The room temperature of the card's mill (``thermal.ambient_C``, degC)."""
        from ..config import load_card

        return float(load_card(self._input("card")).thermal.ambient_C)

    def rpm_max(self) -> float:
        """The highest sun-disc speed of the card's mill (rpm): a logged or stated rpm above it is refused."""
        from ..config import load_card

        return float(load_card(self._input("card")).mill.rpm_max)

    # --- reads -----------------------------------------------------------------------------
    def actions(self) -> list[Action]:
        return [Action(*r) for r in self.con.execute(
            "SELECT id, t0_h, t1_h, hours, rpm, milling FROM actions ORDER BY t0_h")]

    def clock_h(self) -> float:
        r = self.con.execute("SELECT MAX(t1_h) FROM actions").fetchone()[0]
        return 0.0 if r is None else float(r)

    def _observations(self, upto_h: float, ends=()) -> dict[float, dict]:
        """Observations at times <= upto_h: {t: {"s_um", "r", "temperature_c"}}, keyed by their
        estimator node (:func:`_node_times`: times within EPS_H of an action end in ``ends`` or of
        one another are one time); a node's samples in the order they were stored."""
        lim = (upto_h + EPS_H,)
        samples = [(int(sid), float(t)) for sid, t in self.con.execute(
            "SELECT id, t_h FROM samples WHERE t_h <= ? ORDER BY t_h, id", lim)]
        temps = [(float(t), float(T)) for t, T in self.con.execute(
            "SELECT t_h, temperature_c FROM temperatures WHERE t_h <= ? ORDER BY t_h, id", lim)]
        node = _node_times(ends, [t for _, t in samples] + [t for t, _ in temps])
        obs: dict[float, dict] = {}
        for sid, t in sorted(samples, key=lambda st: (node[st[1]], st[0])):  # exact times: ORDER BY t_h, id
            s, r = self.particles(sid)
            o = obs.setdefault(node[t], {"s_um": [], "r": [], "temperature_c": None})
            o["s_um"].append(s)
            o["r"].append(r)
        for t, T in temps:
            o = obs.setdefault(node[t], {"s_um": [], "r": [], "temperature_c": None})
            o["temperature_c"] = T
        return obs

    def particles(self, sample_id: int) -> tuple[np.ndarray, np.ndarray]:
        rows = self.con.execute("SELECT s_um, r FROM particles WHERE sample_id = ? ORDER BY particle_id",
                                (sample_id,)).fetchall()
        a = np.array(rows, dtype=float).reshape(-1, 2)
        return a[:, 0], a[:, 1]

    def last_node(self) -> tuple[int, float, dict]:
        r = self.con.execute("SELECT id, t_h, estimate FROM estimator_states ORDER BY t_h DESC, id DESC LIMIT 1"
                             ).fetchone()
        return int(r[0]), float(r[1]), json.loads(r[2])

    def prior_estimate(self) -> dict | None:
        """The estimate dict of the prior (the card's starting powder, stored before batch time 0), or None."""
        r = self.con.execute("SELECT estimate FROM estimator_states WHERE t_h < 0 ORDER BY id DESC LIMIT 1").fetchone()
        return None if r is None else json.loads(r[0])

    def estimates(self) -> list[tuple[float, dict]]:
        """(t_h, estimate dict) of every node after the prior."""
        return [(float(t), json.loads(e)) for t, e in self.con.execute(
            "SELECT t_h, estimate FROM estimator_states WHERE t_h >= 0 ORDER BY t_h, id")]

    def latest_plan(self):
        r = self.con.execute("SELECT id, t_h, rpm, milling, interval_h, advice, controller_state FROM plans "
                             "ORDER BY id DESC LIMIT 1").fetchone()
        return r

    def plan_before(self, t_h: float):
        """The latest advice given before batch time ``t_h`` (the controller's previous decision), or None.

        An advice repeated at the same logged time starts from this one too, so the same database
        gives the same advice however often ``advise`` runs."""
        return self.con.execute("SELECT id, t_h, rpm, milling, interval_h, advice, controller_state FROM plans "
                                "WHERE t_h < ? ORDER BY id DESC LIMIT 1", (t_h - EPS_H,)).fetchone()

    # --- the estimator's timeline ------------------------------------------------------------
    def _restore_node(self, node_id: int) -> float:
        blob, t = self.con.execute("SELECT state, t_h FROM estimator_states WHERE id = ?", (node_id,)).fetchone()
        state = db.unpack(blob, f"{self.folder}: estimator state {node_id}")
        lp = self.loop
        lp.estimator.set_state(state["estimator"])
        lp.mill.set_state(state["mill"])
        lp.est = dict(state["est"])
        return float(t)

    def _write_node(self, t_h: float) -> None:
        lp = self.loop
        state = {"estimator": lp.estimator.get_state(), "mill": lp.mill.get_state(), "est": lp.est}
        est = dict(lp.est)
        est["t_h"] = t_h
        self.con.execute("INSERT INTO estimator_states (t_h, state, estimate, created_at) VALUES (?, ?, ?, ?)",
                         (t_h, db.pack(state), json.dumps(est), db.now()))

    def _pieces(self, acts: list[Action], a: float, b: float) -> list[tuple[float, float, float]]:
        """(rpm, milling, hours) of the logged inputs between a and b (an action cut keeps mill-then-rest)."""
        out = []
        for act in acts:
            lo, hi = max(a, act.t0_h), min(b, act.t1_h)
            if hi <= lo + EPS_H:
                continue
            if abs(lo - act.t0_h) < EPS_H and abs(hi - act.t1_h) < EPS_H:
                out.append((act.rpm, act.milling, act.hours))  # the whole action, exactly as logged
                continue
            mill_end = act.t0_h + act.milling * act.hours
            m_h = max(0.0, min(hi, mill_end) - lo)
            out.append((act.rpm, m_h / (hi - lo), hi - lo))
        return out

    def _replay(self, invalidate_from_h: float | None = None) -> int:
        """Bring the stored estimator nodes up to the logged clock; returns the nodes written."""
        if invalidate_from_h is not None:
            self.con.execute("DELETE FROM estimator_states WHERE t_h >= ?", (invalidate_from_h - EPS_H,))
        node_id, t_from, _ = self.last_node()
        self._restore_node(node_id)
        clock = self.clock_h()
        acts = self.actions()
        ends = [a.t1_h for a in acts]
        obs = self._observations(clock, ends)  # a sample a rounding off an action end is at that node
        times = set(ends) | set(obs)
        bounds = sorted(t for t in times if t > t_from + EPS_H and t <= clock + EPS_H)
        lp, prev, n = self.loop, max(t_from, 0.0), 0
        for tau in bounds:
            for rpm, milling, hours in self._pieces(acts, prev, tau):
                lp.apply(rpm, milling, hours)
            o = obs.get(tau)
            if o is not None and o["s_um"]:
                lp.observe_at(np.concatenate(o["s_um"]), np.concatenate(o["r"]), o["temperature_c"])
            elif o is not None:
                lp.observe_at(temperature_c=o["temperature_c"])
            else:
                lp.observe_at()
            self._write_node(tau)
            prev, n = tau, n + 1
        return n


def _node_times(ends, times) -> dict[float, float]:
    """The estimator node of each observation time in ``times``: the action end in ``ends`` within
    EPS_H of it (the logged clock's value), else the earliest of the observation times within EPS_H
    of one another (a sample at 0.3 h and a reading at 0.1 + 0.2 h are one time, as ``sample``
    takes them). Exact times are their own nodes."""
    e = np.array(sorted({float(x) for x in ends}), dtype=float)
    out: dict[float, float] = {}
    anchor = None
    for t in sorted({float(x) for x in times}):
        k = int(np.searchsorted(e, t))
        near = [float(x) for x in e[max(k - 1, 0):k + 1] if abs(float(x) - t) <= EPS_H]
        if near:
            out[t] = min(near, key=lambda x: abs(x - t))
            continue
        if anchor is None or t - anchor > EPS_H:
            anchor = t
        out[t] = anchor
    return out


def _filter_settings(changes: dict, particles: int, source: str):
    """FilterSettings from a campaign's recorded changes and particle count; bad ones are a
    one-line InputError naming ``source`` and the field."""
    from ..config import validate
    from ..estimate import FilterSettings

    return validate(FilterSettings, {**changes, "n_particles": particles}, source)


# --- verbs -----------------------------------------------------------------------------------------
def init(folder, model, controller, target, hours: float | None = None, temperature_max_c: float | None = None,
         seed: int = 0, particles: int = 1000, identify: bool = False, progress=None,
         estimator: dict | None = None) -> dict:
    """Start a campaign in ``folder``: copy the inputs, write the prior estimator state.

    Parameters
    ----------
    folder : path-like
        New campaign folder (refused if it already holds one).
    model : path-like
        Model card (``models/*.toml``); its ``.moments.toml`` coefficients are copied with it.
    controller : path-like
        Controller config (``controllers/*.toml``).
    target : dict or str
        Target, e.g. ``{"d50_um": 45}`` or ``"s_mean_um=40,r_mean=0.05"``: a dict's values are
        numbers (text such as ``"45"`` is refused; :func:`bmctl.campaign.targets.check`), text is
        read by :func:`bmctl.campaign.targets.parse`.
    hours : float, optional
        Batch length (default: the card's ``process.hours``).
    temperature_max_c : float, optional
        Vial-temperature ceiling (default: the controller config's).
    seed : int, optional
        Seed of the filter's generator, >= 0.
    particles : int, optional
        Filter particles, 50 to 200000 (:data:`PARTICLES_RANGE`, as ``--particles``).
    identify : bool, optional
        Identify the card's moment coefficients first when it has none of its own
        (:func:`bmctl.moments.for_card`); else such a card is refused.
    progress : callable, optional
        Progress lines of that identification.
    estimator : dict, optional
        Particle-filter settings (fields of :class:`bmctl.estimate.FilterSettings` other than
        the particle count) recorded with the campaign; default :data:`CAMPAIGN_FILTER`.

    Returns
    -------
    dict
        The campaign's meta data.

    Raises
    ------
    InputError
        A bad argument, before anything is written. ``seed`` and ``particles`` are whole numbers
        (an integral float such as ``1000.0`` is taken as its integer; text such as
        ``"3"``, ``True``/``False`` and fractions such as ``50.7`` are refused).
    """
    # the whole-number arguments first: cheap, and nothing (an identification included) runs on bad ones
    seed = _whole(seed, arg("seed"), 0)
    particles = _whole(particles, arg("particles"), *PARTICLES_RANGE)
    from ..config import load_card
    from ..control.config import TARGET_KEYS, check_ceiling, check_dwell_interval, check_lqr_track, load_controller
    from ..moments.coeffs import coeffs_path

    card_p, ctrl_p = Path(model), Path(controller)
    card = load_card(card_p)
    cfg = load_controller(ctrl_p)
    check_dwell_interval(cfg, str(ctrl_p))  # as a trial: a minimum the interval-by-interval guard cannot keep
    if cfg.kind in ("mpc", "lqr"):  # no speed left to mill at on this mill: refused now, not at the first advise
        from ..control.base import check_rpm_range

        check_rpm_range(cfg, float(card.mill.rpm_max))
    for_card(card_p, identify=identify, progress=progress)  # the card's own coefficients, or refuse
    # the messages name the argument, `target` (the command parses --target itself and passes the dict)
    tgt = tg.parse(target, arg("target")) if isinstance(target, str) else tg.check(target, arg("target"))
    if not tgt and cfg.kind != "recipe":
        raise InputError(f"{arg('target')}: a feedback controller ({cfg.kind}) needs a target")
    if cfg.kind == "lqr" and all(k in TARGET_KEYS for k in tgt):  # one the LQR cannot track: refused now
        check_lqr_track(cfg.lqr.track, tgt, arg("target"), str(ctrl_p))
    H = float(card.process.hours) if hours is None else _finite(hours, arg("hours"), HOURS_MIN, MAX_HOURS)
    from ..control.design import check_batch

    # as `bmctl design --hours` and a trial's hours: a batch under the mill's minimum milling period is no batch
    check_batch(H, cfg, "target", arg("hours") if hours is not None else f"{card_p}: process.hours", str(ctrl_p))
    Tmax = None if temperature_max_c is None else _finite(temperature_max_c, arg("temperature_max_c"), -50, 400)
    if Tmax is not None and Tmax <= card.thermal.ambient_C:
        raise InputError(f"{arg('temperature_max_c')}: {Tmax:g} °C is not above the card's ambient temperature "
                         f"(thermal.ambient_C = {card.thermal.ambient_C:g} °C): a resting vial is already at the ambient")
    if Tmax is None:
        check_ceiling(cfg, card, str(ctrl_p))
    if estimator is not None:
        _filter_settings(estimator, particles, "estimator")
    folder = Path(folder)
    inp = folder / INPUTS
    made = [p for p in (folder, inp) if not p.exists()]
    if os.path.lexists(inp) and not inp.is_dir():  # "inputs: File exists" from mkdir said nothing more
        raise InputError(f"{inp}: is a file, not a folder (the campaign keeps copies of its inputs there)")
    files = {"card": (card_p, inp / card_p.name), "controller": (ctrl_p, inp / f"controller-{ctrl_p.name}")}
    if coeffs_path(card_p).exists():
        files["moments"] = (coeffs_path(card_p), coeffs_path(inp / card_p.name))
    if not db.db_path(folder).exists():  # a folder that holds a campaign: db.create's refusal says so
        for _, dst in files.values():
            if os.path.lexists(dst):
                raise _input_exists(dst)
    copied: list[Path] = []
    created: list[Path] = []  # the database, once db.create has made it (a refusal makes nothing)
    try:
        con = db.create(folder, made=created)
        try:
            inp.mkdir(exist_ok=True)
            for src, dst in files.values():
                try:  # never over a file of the user's (one made since the check above included)
                    out = open(dst, "xb")
                except FileExistsError:
                    raise _input_exists(dst) from None
                copied.append(dst)
                with out, open(src, "rb") as fh:
                    shutil.copyfileobj(fh, out)
            meta = {"inputs": {k: {"source": str(src.resolve()), "file": str(dst.relative_to(folder)),
                                   "sha256": _sha(dst)} for k, (src, dst) in files.items()},
                    "target": tgt, "hours": H, "temperature_max_c": Tmax, "seed": seed,
                    "particles": particles, "estimator": dict(CAMPAIGN_FILTER if estimator is None else estimator),
                    "controller_kind": cfg.kind, "created_at": db.now()}
            with db.transaction(con, where=str(folder)):
                db.init_schema(con)
                db.set_meta(con, **meta)
        finally:
            con.close()
        with Campaign(folder, _new=True) as c, db.transaction(c.con, where=str(folder)):
            c._write_node(-1.0)  # the prior
    except BaseException:  # Ctrl-C, a full disk: no campaign without its prior is left behind
        _undo_init(folder, made, copied, created)
        raise
    return meta


def _undo_init(folder: Path, made: list[Path], copied: list[Path], created: list[Path]) -> None:
    """Remove what a failed :func:`init` wrote: its database (``created``: none when ``db.create``
    refused, as for a folder that already holds a campaign), the input copies and the folders it made
    (``copied`` names only the files it created: a file of the user's in ``inputs/`` is never one)."""
    for p in created:
        db.remove_made(p)
    for p in copied:
        if p.is_file() and not p.is_symlink():
            with contextlib.suppress(OSError):
                p.unlink()
    for d in reversed(made):  # inputs/ first, then the campaign folder; only when empty
        with contextlib.suppress(OSError):
            d.rmdir()


def _input_exists(dst: Path) -> InputError:
    """The refusal of an ``init`` whose input copy would replace a file already in ``inputs/``."""
    return InputError(f"{path_text(dst)}: already exists; campaign init copies its inputs into "
                      f"{path_text(dst.parent)} and never replaces a file there (move it, or choose another folder)")


def repeats(a: dict, b: dict) -> bool:
    """Whether two advices' ``next`` intervals are the same as ``advise`` prints them (rpm while
    milling, milling and rest minutes, interval length)."""
    return (int(a["mill_min"]) == int(b["mill_min"]) and int(a["rest_min"]) == int(b["rest_min"])
            and abs(float(a["interval_h"]) - float(b["interval_h"])) * 60.0 < 1.0
            and (int(a["mill_min"]) == 0 or abs(float(a["rpm"]) - float(b["rpm"])) <= 0.5))


def standing_decision(con, plan_id: int) -> tuple | None:
    """The decision that stands for advice ``plan_id``: its own latest, else the latest one recorded on
    an earlier advice at the same logged time that this advice repeats (:func:`repeats`; advising again
    at one time repeats the advice, and the operator's decision on it still stands). An advice at that
    time that differs (a sample came in between) needs its own decision.

    Returns
    -------
    tuple or None
        ``(accepted, rpm, milling, note, advice_id)``, ``advice_id`` the advice it was recorded on.
    """
    row = con.execute("SELECT t_h, advice FROM plans WHERE id = ?", (plan_id,)).fetchone()
    if row is None:
        return None
    nx = json.loads(row[1])["next"]
    for pid, advice in con.execute("SELECT id, advice FROM plans WHERE abs(t_h - ?) < 1e-6 AND id <= ? "
                                   "ORDER BY id DESC", (row[0], plan_id)).fetchall():
        if pid != plan_id and not repeats(json.loads(advice)["next"], nx):
            return None
        dec = con.execute("SELECT accepted, rpm, milling, note FROM decisions WHERE plan_id = ? ORDER BY id DESC "
                          "LIMIT 1", (pid,)).fetchone()
        if dec is not None:
            return (*dec, pid)
    return None


def _deviation(c: Campaign, t0: float, rpm: float, milling: float, hours: float) -> tuple[int | None, str]:
    """(plan id, text) comparing a logged action with the advice (and decision) for its start time:
    the advice as printed (rpm, milling and rest minutes, interval); empty when they agree."""
    row = c.con.execute("SELECT id, advice FROM plans WHERE abs(t_h - ?) < 1e-6 ORDER BY id DESC LIMIT 1",
                        (t0,)).fetchone()
    if row is None:
        return None, ""
    pid = row[0]
    nx = json.loads(row[1])["next"]
    p_rpm, p_mill_min, p_h = float(nx["rpm"]), float(nx["mill_min"]), float(nx["interval_h"])
    dec = standing_decision(c.con, pid)  # its own, or one on an earlier advice at this time that it repeats
    mill_min = milling * hours * 60.0
    diffs = []
    if mill_min >= 1.0 and p_mill_min >= 1.0 and abs(rpm - p_rpm) > 0.5:
        diffs.append(f"rpm {rpm:g} (recommended {p_rpm:g})")
    if abs(mill_min - p_mill_min) >= 1.0:
        if mill_min < 1.0:
            diffs.append(f"rest instead of milling (recommended {p_rpm:g} rpm for {p_mill_min:.0f} min)")
        else:
            diffs.append(f"milling {mill_min:.0f} min (recommended {p_mill_min:.0f})")
    if abs(hours - p_h) * 60 >= 1.0:
        diffs.append(f"interval {hours * 60:.0f} min (recommended {p_h * 60:.0f})")
    if not diffs:
        return pid, ""
    how = "no decision recorded" if dec is None else ("advice accepted" if dec[0] else "advice rejected")
    return pid, f"deviation from the recommendation ({how}): " + ", ".join(diffs)


def log(folder, rpm: float, hours: float, milling: float = 1.0, temperature_c: float | None = None,
        from_h: float | None = None, campaign: Campaign | None = None) -> dict:
    """Record what the mill ran: ``rpm`` for ``milling * hours``, then rest, from ``from_h``
    (default: the end of the last logged interval); ``rpm = 0`` or ``milling = 0`` is a rest
    (recorded as 0 rpm, no milling). A share strictly between 0 and 1 must leave a milling and a
    rest phase of at least 6 s each, as a schedule file's (:func:`bmctl.schedule.short_phase`). A
    vial-temperature reading at its end enters the estimator. Overlaps (time going backwards) and
    gaps are refused.

    Parameters
    ----------
    folder : path-like
        The campaign folder.
    rpm : float
        The speed milled at (0: a rest), at most the card's ``mill.rpm_max``.
    hours : float
        The interval's length (h): one second at least, ending at or before the batch end.
    milling : float, optional
        The share of ``hours`` milled, first (0 to 1; default 1).
    temperature_c : float, optional
        The vial temperature read at the interval's end (°C, -50 to 400).
    from_h : float, optional
        Where the interval starts (h); must be the end of the last logged interval (default).
    campaign : Campaign, optional
        An open campaign to use (and leave open); default: ``folder`` is opened and closed.

    Returns
    -------
    dict
        ``t0_h, t1_h, rpm, milling`` (as recorded), ``deviation`` (empty when the advice for the
        interval's start was followed), ``warnings`` (the reading above the ceiling or far from the
        estimate; the estimate above the ceiling) and the new ``estimate``.
    """
    rpm = _finite(rpm, arg("rpm"), 0)
    hours = _finite(hours, arg("hours"), HOURS_MIN, MAX_HOURS)  # one second at least (bmctl.limits)
    milling = _finite(milling, arg("milling"), 0, 1)
    if rpm == 0 or milling == 0:  # a rest: the mill stood still for the whole interval
        rpm, milling = 0.0, 0.0
    # as a schedule file's share: no milling or rest phase under 6 s; a phase under EPS_H (microseconds)
    # is a share of 1 or 0 rounded (bmctl.loop.interval_share of a short last interval), not a phase
    share = milling if min(milling, 1.0 - milling) * hours >= EPS_H else float(round(milling))
    why = short_phase(hours, rpm, share, "interval")
    if why:
        raise InputError(f"{arg('milling')} {milling:.12g} of {arg('hours')} {hours:.12g}: {why}")
    T = None if temperature_c is None else _finite(temperature_c, arg("temperature_c"), -50, 400)
    c = campaign or Campaign(folder)
    try:
        if rpm > c.rpm_max():
            raise InputError(f"{arg('rpm')} {rpm:.12g}: above the mill's rpm_max ({c.rpm_max():g}) in the "
                             "campaign's card")
        with db.transaction(c.con, where=str(folder)):
            clock = c.clock_h()
            t0 = clock if from_h is None else _finite(from_h, arg("from_h"), 0)
            if t0 < clock - EPS_H:
                raise InputError(f"{arg('from_h')} {t0:g}: overlaps the logged interval ending at {clock:g} h "
                                 "(time going backwards); the log is append-only")
            if t0 > clock + EPS_H:
                raise InputError(f"{arg('from_h')} {t0:g}: leaves a gap after {clock:g} h; log what the mill did "
                                 f"from {clock:g} h first (a rest is {arg('rpm')} 0)")
            t0 = clock
            t1 = t0 + hours
            if t1 > c.meta["hours"] + 1e-6:
                raise InputError(f"{arg('hours')} {hours:g}: ends at {t1:g} h, after the batch end "
                                 f"({c.meta['hours']:g} h)")
            pid, dev = _deviation(c, t0, rpm, milling, hours)
            cur = c.con.execute("INSERT INTO actions (t0_h, t1_h, hours, rpm, milling, plan_id, deviation, logged_at)"
                                " VALUES (?, ?, ?, ?, ?, ?, ?, ?)", (t0, t1, hours, rpm, milling, pid, dev, db.now()))
            if T is not None:
                c.con.execute("INSERT INTO temperatures (t_h, temperature_c, action_id, logged_at) VALUES (?, ?, ?, ?)",
                              (t1, T, cur.lastrowid, db.now()))
            c._replay()
            est = c.last_node()[2]
            warnings = c.temperature_warnings(since_h=t0)
    finally:
        if campaign is None:
            c.close()
    return {"t0_h": t0, "t1_h": t1, "rpm": rpm, "milling": milling, "deviation": dev, "warnings": warnings,
            "estimate": est}


def sample(folder, at_h: float, inputs, um_per_px: float | None = None, campaign: Campaign | None = None,
           accept_unusable: bool = False, scale_bar_um: float | None = None) -> dict:
    """Measure a sample taken at batch time ``at_h`` (images and/or particle tables, as
    ``bmctl measure``), store its particles and update the estimator (now if ``at_h`` is
    logged, else when the log reaches it). An image whose measurement verdict is ``unusable``
    is refused unless ``accept_unusable``; doubtful images are listed in ``warnings``.

    Parameters
    ----------
    folder : path-like
        The campaign folder.
    at_h : float
        Batch time the sample was taken at (h, at most the batch end).
    inputs : sequence of path-like or ParticleTable, or one of them
        Micrographs and/or particle tables (CSV as ``bmctl measure`` writes, or in memory), pooled.
    um_per_px : float, optional
        The images' pixel size (µm; default: read from each image, as ``bmctl measure``); tables are
        not rescaled.
    campaign : Campaign, optional
        An open campaign to use (and leave open); default: ``folder`` is opened and closed.
    accept_unusable : bool, optional
        Keep an image (or a table's image) whose verdict is ``unusable`` (as ``--accept-unusable``).
    scale_bar_um : float, optional
        The length written on the images' scale bar (µm), which then gives their pixel size (as
        ``bmctl measure --scale-bar-um``). ``um_per_px`` and ``scale_bar_um`` are refused where every
        input is a table.

    Returns
    -------
    dict
        ``sample_id, n, s_median_um, r_median, applied`` (False: waits for the log), ``replayed``
        (estimator nodes recomputed), ``estimate`` and ``warnings`` (doubtful images; a filter the
        sample left nearly degenerate, :func:`bmctl.campaign.advice.band_warning`).

    An input whose bytes are another input's of the same command, or an input stored before (its
    SHA-256, ``sample_inputs``), or whose particles are a stored sample's or part of one, is
    refused: it would read as a sample larger than it is.
    """
    at_h = _finite(at_h, arg("at_h"), 0)
    if isinstance(inputs, (str, os.PathLike)) or not hasattr(inputs, "__iter__"):  # one input, not a list of them
        inputs = [inputs]
    inputs = list(inputs)
    if not inputs:
        raise InputError("sample: give at least one image or particle table")
    for given, name in ((um_per_px, "um_per_px"), (scale_bar_um, "scale_bar_um")):
        if given is not None:  # a value out of range is said first, as for an image
            from ..measure.scale import check_scale

            check_scale(given, name)
        if given is not None and all(not isinstance(i, (str, os.PathLike)) or Path(i).suffix.lower() == ".csv"
                                     for i in inputs):  # a pixel size nothing would use (tables in memory too)
            raise InputError(f"{arg(name)}: every input is a particle table (sizes in µm already); it applies "
                             "to micrographs only")
    refuse_repeats(inputs, "sample: ")
    digests = [_digest(i) for i in inputs]
    _refuse_same_bytes(inputs, digests)
    if campaign is None:  # a campaign this user may not record to: refused before the images are measured
        db.refuse_read_only(folder)
    # before the lock: may take seconds
    table, images, x, y, reports, counts = _measure(inputs, um_per_px, accept_unusable, arg("um_per_px"),
                                                       arg("accept_unusable=True"), scale_bar_um)
    c = campaign or Campaign(folder)
    try:
        if at_h > c.meta["hours"] + 1e-6:
            raise InputError(f"{arg('at_h')} {at_h:g}: after the batch end ({c.meta['hours']:g} h)")
        with db.transaction(c.con, where=str(folder)):
            db.upgrade(c.con)  # a version-1 campaign gets sample_inputs (rolled back if refused below)
            _refuse_stored_table(c, table, inputs)
            _refuse_stored_inputs(c, inputs, digests)
            _refuse_parts_of_unhashed(c, table, inputs, counts)
            summ = table.summary()
            srcs = [_source(i) for i in inputs]
            # stored at its estimator node's time (an action end, or a stored sample's, within EPS_H)
            at_h = _node_times([a.t1_h for a in c.actions()],
                               [at_h] + [float(t) for (t,) in c.con.execute("SELECT t_h FROM samples")])[at_h]
            scaled = um_per_px if any("image" in rep for rep in reports) else None  # a table is not rescaled
            cur = c.con.execute("INSERT INTO samples (t_h, sources, um_per_px, n, s_median_um, r_median, report, "
                                "logged_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                                (at_h, json.dumps(srcs), scaled, len(table), summ["s_median_um"],
                                 summ["r_median"], json.dumps(reports), db.now()))
            sid = cur.lastrowid
            rows = [(sid, i + 1, path_text(images[i]), None if not np.isfinite(x[i]) else float(x[i]),
                     None if not np.isfinite(y[i]) else float(y[i]), float(table.area_um2[i]),
                     float(table.perimeter_um[i]), float(table.s_um[i]), float(table.r[i])) for i in range(len(table))]
            _insert_particles(c.con, rows)
            c.con.executemany("INSERT INTO sample_inputs (sample_id, position, source, sha256) VALUES (?, ?, ?, ?)",
                              [(sid, k + 1, src, h) for k, (src, h) in enumerate(zip(srcs, digests)) if h is not None])
            clock = c.clock_h()
            applied = at_h <= clock + EPS_H
            n = c._replay(invalidate_from_h=at_h) if applied else 0
            est = c.last_node()[2]
            warnings = [w for rep in reports for w in rep.get("verdict_warnings", [])]
            if applied:
                warnings += c.band_warnings(since_h=at_h - 2 * EPS_H)  # the nodes it recomputed, from at_h on
    finally:
        if campaign is None:
            c.close()
    return {"sample_id": sid, "t_h": at_h, "n": len(table), "s_median_um": summ["s_median_um"],
            "r_median": summ["r_median"], "applied": applied, "replayed": n, "estimate": est, "clock_h": clock,
            "warnings": warnings}


def _source(item) -> str:
    """How a sample's input is recorded (``samples.sources``, ``sample_inputs.source``)."""
    return "(table)" if hasattr(item, "s_um") else path_text(item)


def _name(item, k: int) -> str:
    """An input as a message names it (``k``: its place in the command, for a table given in memory)."""
    return f"table {k + 1} (in memory)" if hasattr(item, "s_um") else path_text(item)


def _same(item) -> str:
    """What :func:`_digest` hashed of an input, as a refusal names it."""
    return "the same columns" if hasattr(item, "s_um") else "the same bytes"


#: what a particle table given in memory is hashed with before its columns (never a file's bytes alone)
_TABLE_TAG = b"bmctl particle table in memory\0"


def _digest(item) -> str | None:
    """SHA-256 (hex) of an input's bytes: a file as stored (read in blocks), a particle table given in
    memory by its four columns as little-endian float64 after :data:`_TABLE_TAG`. None for a file that
    cannot be read (the measurement then says why, in its own words)."""
    from ..io import check_input_file

    h = hashlib.sha256()
    if hasattr(item, "s_um"):
        h.update(_TABLE_TAG)
        for col in ("area_um2", "perimeter_um", "s_um", "r"):
            h.update(np.ascontiguousarray(getattr(item, col), dtype="<f8").tobytes())
        return h.hexdigest()
    try:
        p = check_input_file(item)  # a regular file of a sane size (no FIFO, no device)
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # swapped for a FIFO after the check
                return None
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except (InputError, OSError):
        return None
    return h.hexdigest()


def _refuse_same_bytes(inputs: list, digests: list) -> None:
    """Refuse two inputs of one command with the same bytes (one file under two names, or a copy):
    one line naming both. The same path twice is :func:`bmctl.measure.names.refuse_repeats`'s."""
    seen: dict[str, int] = {}
    for k, h in enumerate(digests):
        if h is None:
            continue
        if h in seen:
            j = seen[h]
            raise InputError(f"sample: {_name(inputs[k], k)}: {_same(inputs[k])} as {_name(inputs[j], j)} (one "
                             "image or table given twice would read as a sample twice its size)")
        seen[h] = k


#: how far a particle read back from a table may lie from the one measured (s relative, r absolute):
#: ``bmctl measure`` writes 7 significant digits (:func:`bmctl.measure.tables.write_table`), s and r
#: then come back within 1e-6 of the image's
SAME_PARTICLE_TOL = 1e-6


def _same_particles(s_old, r_old, s_new, r_new) -> bool:
    """True when two samples hold the same particles in the same order, within :data:`SAME_PARTICLE_TOL`."""
    return (s_old.shape == s_new.shape and r_old.shape == r_new.shape
            and bool(np.all(np.abs(s_old - s_new) <= SAME_PARTICLE_TOL * np.maximum(s_old, s_new)))
            and bool(np.all(np.abs(r_old - r_new) <= SAME_PARTICLE_TOL)))


def _refuse_stored_table(c: Campaign, table, inputs: list) -> None:
    """Refuse a sample whose particles are a stored sample's (the same file or image entered by a
    second ``sample``, or an image and the ``bmctl measure`` table of it, in either order: their
    values agree to the table's 7 digits, :data:`SAME_PARTICLE_TOL`): it would read as a sample
    twice its size, as a file named twice in one command would (:func:`bmctl.measure.names.refuse_repeats`)."""
    if not len(table):
        return
    s_new, r_new = np.asarray(table.s_um, dtype=float), np.asarray(table.r, dtype=float)
    s0, r0, tol = float(s_new[0]), float(r_new[0]), SAME_PARTICLE_TOL
    for sid, t_h, srcs in c.con.execute(
            "SELECT s.id, s.t_h, s.sources FROM samples s JOIN particles p ON p.sample_id = s.id AND p.particle_id = 1 "
            "WHERE s.n = ? AND p.s_um BETWEEN ? AND ? AND p.r BETWEEN ? AND ? ORDER BY s.id",
            (len(table), s0 * (1 - 2 * tol), s0 * (1 + 2 * tol), r0 - 2 * tol, r0 + 2 * tol)).fetchall():
        s_old, r_old = c.particles(int(sid))
        if _same_particles(s_old, r_old, s_new, r_new):
            new = ", ".join(_name(i, k) for k, i in enumerate(inputs))
            raise InputError(f"sample: {new}: the same particles as sample {sid} at {t_h:g} h, from "
                             f"{', '.join(json.loads(srcs))} (one sample entered twice, as one table or as an image "
                             "and its table, would read as a sample twice its size); take another sample")


def _refuse_stored_inputs(c: Campaign, inputs: list, digests: list) -> None:
    """Refuse an input whose bytes are those of an input stored before (``sample_inputs``), alone or
    as part of a larger sample: one line naming both."""
    for k, h in enumerate(digests):
        if h is None:
            continue
        row = c.con.execute("SELECT i.source, s.id, s.t_h FROM sample_inputs i JOIN samples s ON s.id = i.sample_id "
                            "WHERE i.sha256 = ? ORDER BY s.id, i.position LIMIT 1", (h,)).fetchone()
        if row is not None:
            raise InputError(f"sample: {_name(inputs[k], k)}: {_same(inputs[k])} as {row[0]}, entered in sample "
                             f"{row[1]} at {row[2]:g} h (one image or table entered twice would read as a sample twice "
                             "its size); take another sample")


def _refuse_parts_of_unhashed(c: Campaign, table, inputs: list, counts: list) -> None:
    """Refuse an input whose particles are, in order, a run of the particles of a sample stored
    without input hashes (a campaign written before ``sample_inputs``): the particles of each input
    of a sample are stored one after another, so an input entered again is such a run."""
    if c.con.execute("SELECT 1 FROM samples WHERE id NOT IN (SELECT sample_id FROM sample_inputs) LIMIT 1"
                     ).fetchone() is None:
        return
    s_all, r_all = np.asarray(table.s_um, dtype=float), np.asarray(table.r, dtype=float)
    ends = np.cumsum(counts)
    for k, (a, b) in enumerate(zip(ends - counts, ends)):
        s_new, r_new = s_all[a:b], r_all[a:b]
        if not s_new.size:
            continue
        for sid, t_h in c.con.execute(
                "SELECT DISTINCT s.id, s.t_h FROM samples s JOIN particles p ON p.sample_id = s.id "
                "WHERE p.s_um = ? AND p.r = ? AND s.id NOT IN (SELECT sample_id FROM sample_inputs) ORDER BY s.id",
                (float(s_new[0]), float(r_new[0]))).fetchall():
            s_old, r_old = c.particles(int(sid))
            for i in np.flatnonzero((s_old == s_new[0]) & (r_old == r_new[0])):
                if (np.array_equal(s_old[i:i + s_new.size], s_new)
                        and np.array_equal(r_old[i:i + s_new.size], r_new)):
                    raise InputError(f"sample: {_name(inputs[k], k)}: the same particles as part of sample {sid} at "
                                     f"{t_h:g} h (one image or table entered twice would read as a sample twice its "
                                     "size); take another sample")


def _insert_particles(con, rows) -> None:
    """Insert a sample's particles (a function of its own so that tests can interrupt here)."""
    con.executemany("INSERT INTO particles VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)


def ensure_coefficients(folder, identify: bool = False, progress=None):
    """The moment model of the campaign's copy of its card (:func:`bmctl.moments.for_card`): refuses
    coefficients of another card, or identifies the copy with ``identify``.

    Parameters
    ----------
    folder : path-like
        The campaign.
    identify : bool, optional
        Identify the copy's coefficients when it has none of its own.
    progress : callable, optional
        Progress lines of that identification.
    """
    with Campaign(folder) as c:
        return for_card(c._input("card"), identify=identify, progress=progress)


def advise(folder, campaign: Campaign | None = None, progress=None) -> dict:
    """Recommend the next action from the current estimate.

    Parameters
    ----------
    folder : path-like
        The campaign folder.
    campaign : Campaign, optional
        An open campaign to use (and leave open, its compiled solvers kept); default: ``folder`` is
        opened and closed.
    progress : callable, optional
        Called with one line per step (the command prints them on stderr).

    Returns
    -------
    dict
        ``t_h``; ``warnings`` (readings since the previous advice above the ceiling or far from the
        estimate; the estimate above the ceiling); ``estimate`` (values with ``_q05``/``_q95``); ``target`` and ``controller_target``;
        ``next`` (rpm, milling share, milling and rest minutes, interval); ``schedule`` to the batch
        end; ``end`` (median and 90 % band of each moment at the batch end; ``end_nominal``: the
        controller's own prediction); ``reachable`` per target; ``binding`` constraints;
        ``solver`` (status line), ``solver_status``, ``solver_ok``, ``fallback``; ``solve_ms``,
        ``advise_ms``; ``plan_id``; ``sampling``: how closely the latest sample reads the mean size
        and the particle count that would read it within the controller's tolerance
        (:func:`bmctl.campaign.advice.sampling`; None before the first sample); ``sample_first``:
        why another sample should be taken at this batch time before the move, or None
        (:func:`bmctl.campaign.advice.sample_first`); ``notes``: what the advice stands on when
        that is not the mill's own data (before the first sample: the card's starting powder).
    """
    from ..loop import interval_length, interval_share

    t_start = time.perf_counter()
    say = progress or (lambda text: None)
    c = campaign or Campaign(folder)
    try:
        with db.transaction(c.con, where=str(folder)):
            if c._loop is None:
                say("building the moment model, the filter and the controller")
            lp = c.loop
            clock = c.clock_h()
            _, t_node, est = c.last_node()
            c._restore_node(c.last_node()[0])
            prev = c.plan_before(clock)
            if prev is not None:
                lp.controller.set_state(db.unpack(prev[6], f"{folder}: controller state"))
            else:
                lp.controller.reset()
            earlier = c.con.execute("SELECT MAX(t_h) FROM plans WHERE t_h < ?", (clock - 1e-6,)).fetchone()[0]
            since = None if earlier is None else float(earlier)
            warnings = c.temperature_warnings(since_h=since) + c.band_warnings(since_h=since)
            ctrl_target = tg.controller_target(c.meta["target"], est)
            lp.controller.set_target(ctrl_target, t_end_h=c.meta["hours"])
            acts = c.actions()
            lp.u_prev = (acts[-1].rpm, acts[-1].milling) if acts else None
            readings = dict(c.con.execute("SELECT action_id, temperature_c FROM temperatures WHERE action_id IS NOT NULL "
                                          "ORDER BY id"))
            history = [(a.hours, a.rpm, a.milling, readings.get(a.id)) for a in acts]
            say(f"planning from {clock:g} h to the batch end ({c.meta['hours']:g} h)")
            plan, solve_ms = lp.decide_at(clock, history=history)
            say(f"planned in {solve_ms / 1e3:.1f} s: {plan.status.reason or plan.status.solver_status}")
            sched = _schedule(c, plan, clock)
            end = _end_band(c, sched, plan) if sched else {}
            reach, binding = _why(c, plan, sched, end, ctrl_target)
            x_end = np.asarray(plan.x[-1], dtype=float)
            dt = plan.interval_h
            h_next = interval_length(clock, c.meta["hours"], dt) if clock < c.meta["hours"] - EPS_H else 0.0
            mill_min = round(plan.milling * dt * 60.0)
            sampled, sampled_note = _last_sampling(c, clock)
            advice = {
                "t_h": clock, "warnings": warnings, "estimate": est, "target": c.meta["target"],
                "controller_target": ctrl_target,
                # milling: the share of interval_h (the controller's share of its interval ``dt``, as
                # stored and decided, in the same minutes: a short last interval, bmctl.loop.interval_share)
                "next": {"rpm": plan.rpm if mill_min > 0 else 0.0,
                         "milling": interval_share(plan.milling, dt, h_next) if h_next > 0 else plan.milling,
                         "interval_h": h_next,
                         "mill_min": min(mill_min, round(h_next * 60)),
                         "rest_min": max(0, round(h_next * 60) - mill_min)},
                "schedule": sched, "end": end,
                "end_nominal": {"t_h": float(plan.times_h[-1]), "s_mean_um": x_end[0], "s_std_um": x_end[1],
                                "r_mean": x_end[2], "r_std": x_end[3], "temperature_c": x_end[4]},
                "reachable": reach, "binding": binding, "solver": plan.status.line(),
                "solver_status": plan.status.solver_status, "fallback": plan.status.fallback,
                "solver_ok": bool(plan.status.success), "solve_ms": float(solve_ms),
                "pending_samples": c.con.execute("SELECT COUNT(*) FROM samples WHERE t_h > ?",
                                                 (clock + EPS_H,)).fetchone()[0],
                "sampling": sampled,
            }
            advice["sample_first"] = _sample_first(c, advice, clock, history)
            advice["notes"] = _notes(c, est, clock) + ([sampled_note] if sampled_note else [])
            advise_ms = (time.perf_counter() - t_start) * 1e3
            advice["advise_ms"] = advise_ms
            cur = c.con.execute("INSERT INTO plans (t_h, rpm, milling, interval_h, advice, controller_state, "
                                "advise_ms, created_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                                (clock, float(plan.u_apply[0]), float(plan.u_apply[1]), dt, json.dumps(advice),
                                 db.pack(lp.controller.get_state()), advise_ms, db.now()))
            advice["plan_id"] = cur.lastrowid
    finally:
        if campaign is None:
            c.close()
    return advice


#: a 90 % interval of the mean size wider than this share of it (either side) after a sample is
#: noted as an uncertain estimate
UNCERTAIN_HALF_WIDTH = 0.25


def _notes(c: Campaign, est: dict, clock: float = 0.0) -> list[str]:
    """What the operator should know about the advice's footing: before the campaign's first sample
    the estimate is the card's starting powder (carried forward by the model over what was logged),
    so a feed that differs from the card is steered as if it did not until a sample shows it; after
    samples, an estimate whose 90 % interval of the mean size is wider than
    :data:`UNCERTAIN_HALF_WIDTH` either side (samples that disagree with the model widen it) is said
    to be uncertain. A sample after ``clock`` waits for the log and is not in the estimate yet.
    """
    if c.con.execute("SELECT COUNT(*) FROM samples WHERE t_h <= ?", (clock + EPS_H,)).fetchone()[0]:
        line = _uncertain(est)
        return [line] if line else []
    return [_no_sample_note(c.loop.model.const.s0_mean_um, est["s_mean_um"], clock)]


def _no_sample_note(s0_um: float, s_um: float, clock: float) -> str:
    """The note of an advice before the campaign's first sample: the estimate is the card's starting
    powder (mean size ``s0_um``), at ``clock`` > 0 carried forward by the model over the logged
    hours to ``s_um``.

    Examples
    --------
    >>> print(_no_sample_note(40.0, 40.0, 0.0))  # doctest: +NORMALIZE_WHITESPACE
    no sample yet: the estimate is the card's starting powder (s_mean_um 40); if the feed may differ, sample
    it first (bmctl campaign sample DIR --at-h 0 FILE) and advise again
    >>> print(_no_sample_note(40.0, 50.54, 2.0))  # doctest: +NORMALIZE_WHITESPACE
    no sample yet: the estimate is the card's starting powder (s_mean_um 40) carried forward by the model
    over the 2 h logged (s_mean_um 50.54 now), not a measurement; sample the powder now (bmctl campaign
    sample DIR --at-h 2 FILE; a kept sample of the feed at --at-h 0) and advise again
    """
    if clock <= EPS_H:
        return (f"no sample yet: the estimate is the card's starting powder (s_mean_um {s0_um:.4g}); if the feed "
                "may differ, sample it first (bmctl campaign sample DIR --at-h 0 FILE) and advise again")
    return (f"no sample yet: the estimate is the card's starting powder (s_mean_um {s0_um:.4g}) carried forward by "
            f"the model over the {clock:g} h logged (s_mean_um {s_um:.4g} now), not a measurement; sample the powder "
            f"now (bmctl campaign sample DIR --at-h {clock:g} FILE; a kept sample of the feed at --at-h 0) and "
            "advise again")


def _uncertain(est: dict) -> str:
    """The note of an uncertain estimate (empty when the interval is narrower than
    :data:`UNCERTAIN_HALF_WIDTH` either side of the mean).

    Examples
    --------
    >>> est = {"s_mean_um": 55.0, "s_mean_um_q05": 29.1, "s_mean_um_q95": 101.6}
    >>> print(_uncertain(est))  # doctest: +NORMALIZE_WHITESPACE
    the estimate is uncertain: s_mean_um 55 [29.1, 101.6] µm (90 %), -47/+85 %: the samples disagree with
    the model or are few; a sample before acting on this advice narrows it
    """
    m, lo, hi = (est.get(k) for k in ("s_mean_um", "s_mean_um_q05", "s_mean_um_q95"))
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in (m, lo, hi)) or m <= 0:
        return ""
    if lo >= m * (1 - UNCERTAIN_HALF_WIDTH) and hi <= m * (1 + UNCERTAIN_HALF_WIDTH):
        return ""
    return (f"the estimate is uncertain: s_mean_um {m:.4g} [{lo:.4g}, {hi:.4g}] µm (90 %), "
            f"{100 * (lo / m - 1):.0f}/+{100 * (hi / m - 1):.0f} %: the samples disagree with the model or are few; "
            "a sample before acting on this advice narrows it")


def _tolerance(c: Campaign) -> float | None:
    """The controller's ``[objective] tolerance`` (None: a controller without one)."""
    obj = getattr(getattr(c.loop.controller, "cfg", None), "objective", None)
    return None if obj is None else float(obj.tolerance)


def _sample_first(c: Campaign, advice: dict, clock: float, history: list) -> str | None:
    """:func:`bmctl.campaign.advice.sample_first` for this advice (None: a controller without an
    ``[objective] tolerance``, or the batch finished); ``history``: the logged intervals as the
    planner takes them."""
    from ..control.planner import milled

    tol = _tolerance(c)
    if tol is None or advice["next"]["interval_h"] <= 0:
        return None
    here, before = c.con.execute("SELECT SUM(ABS(t_h - ?) <= ?), COUNT(*) FROM samples WHERE t_h <= ?",
                                 (clock, EPS_H, clock + EPS_H)).fetchone()
    return sample_first(advice["estimate"], c.meta["target"], tol, advice["next"]["mill_min"],
                        milled(history[-1:]), int(here or 0), int(before))


def _last_sampling(c: Campaign, clock: float) -> tuple[dict | None, str | None]:
    """:func:`bmctl.campaign.advice.sampling` of the latest sample at or before ``clock`` (with every
    other sample taken at that time, pooled as the filter reads them) against the
    controller's ``[objective] tolerance`` (None: no sample yet, or a controller without one), and
    the note that says why it is None for a sample too small to show the spread of sizes
    (:func:`bmctl.campaign.advice.sampling_note`; else None)."""
    tol = _tolerance(c)
    row = c.con.execute("SELECT id, t_h FROM samples WHERE t_h <= ? ORDER BY t_h DESC, id DESC LIMIT 1",
                        (clock + EPS_H,)).fetchone()
    if tol is None or row is None:
        return None, None
    t = float(row[1])  # every sample at that time: the filter reads them as one
    ids = [int(i) for (i,) in c.con.execute("SELECT id FROM samples WHERE ABS(t_h - ?) <= ? ORDER BY id",
                                            (t, EPS_H)).fetchall()]
    s = np.concatenate([c.particles(i)[0] for i in ids])
    out = sampling(s, tol)
    if out is None:
        return None, sampling_note(t, s.size) if s.size < 2 else None
    return {"t_h": t, "samples": len(ids), **out}, None


def decide(folder, accept: bool, rpm: float | None = None, milling: float | None = None, note: str = "",
           campaign: Campaign | None = None) -> dict:
    """Record the operator's decision on the latest advice (which must be for the logged clock).

    Rejecting may state what will be run instead (``rpm``, ``milling``); what the mill then
    ran is what :func:`log` records, and a deviation is reported there, not refused.

    Parameters
    ----------
    folder : path-like
        The campaign folder.
    accept : bool
        True: the advice is run as recommended; False: it is rejected.
    rpm : float, optional
        With a rejection: the speed that will be run instead (at most the card's ``mill.rpm_max``).
    milling : float, optional
        With a rejection: the milling share that will be run instead (0 to 1).
    note : str, optional
        The operator's note, stored with the decision.
    campaign : Campaign, optional
        An open campaign to use (and leave open); default: ``folder`` is opened and closed.

    Returns
    -------
    dict
        ``plan_id``, ``t_h``, ``accepted``, the ``recommended_*`` input (rpm, milling, mill minutes,
        interval), the ``rpm`` and ``milling`` that will be run, and ``replaces`` (earlier decisions
        on the same advice, which this one replaces).
    """
    if not isinstance(accept, (bool, np.bool_)):  # "no" is truthy: it was recorded as an acceptance
        raise TypeError(f"decide: accept must be True or False (got {accept!r})")
    note = "" if note is None else note
    if not isinstance(note, str):
        raise TypeError(f"decide: note must be a str (got {type(note).__name__})")
    if accept and (rpm is not None or milling is not None):
        raise InputError(f"decide: {arg('rpm')}/{arg('milling')} go with {arg('accept=False')} (an accepted advice "
                         "is run as recommended)")
    rpm = None if rpm is None else _finite(rpm, arg("rpm"), 0)
    milling = None if milling is None else _finite(milling, arg("milling"), 0, 1)
    c = campaign or Campaign(folder)
    try:
        if rpm is not None and rpm > c.rpm_max():
            raise InputError(f"{arg('rpm')} {rpm:.12g}: above the mill's rpm_max ({c.rpm_max():g}) in the "
                             "campaign's card")
        with db.transaction(c.con, where=str(folder)):
            plan = c.latest_plan()
            clock = c.clock_h()
            if plan is None or abs(plan[1] - clock) > 1e-6:
                raise InputError(f"{folder}: no advice for the logged time {clock:g} h; run `bmctl campaign advise` first")
            if clock >= c.meta["hours"] - EPS_H:
                raise InputError(f"{folder}: the batch ended at {c.meta['hours']:g} h: nothing left to decide "
                                 f"(`bmctl campaign report {folder}` for the whole campaign)")
            replaced = c.con.execute("SELECT COUNT(*) FROM decisions WHERE plan_id = ?", (plan[0],)).fetchone()[0]
            c.con.execute("INSERT INTO decisions (plan_id, accepted, rpm, milling, note, created_at) VALUES "
                          "(?, ?, ?, ?, ?, ?)", (plan[0], int(bool(accept)), rpm if not accept else plan[2],
                                                 milling if not accept else plan[3], note, db.now()))
    finally:
        if campaign is None:
            c.close()
    nx = json.loads(plan[5]).get("next") or {}
    return {"plan_id": plan[0], "t_h": plan[1], "accepted": bool(accept), "recommended_rpm": plan[2],
            "recommended_milling": plan[3], "recommended_mill_min": nx.get("mill_min"),
            "recommended_interval_h": nx.get("interval_h"), "rpm": plan[2] if accept else rpm,
            "milling": plan[3] if accept else milling, "replaces": int(replaced)}


def status(folder, campaign: Campaign | None = None) -> dict:
    """Where the campaign stands: clock, counts, the current estimate, the latest advice and the
    decision that stands for it (:func:`standing_decision`; ``advice_id`` the advice it was recorded
    on), the deviations, and the temperature warnings since the latest advice.

    Parameters
    ----------
    folder : str or Path
        The campaign folder (``campaign init``'s DIR); opened read-only.
    campaign : Campaign, optional
        An open campaign to read instead (the caller keeps it open).

    Returns
    -------
    dict
        What ``campaign status --json`` prints.
    """
    c = campaign or Campaign(folder, read_only=True)
    try:
        with db.transaction(c.con, write=False, where=str(folder)):
            clock = c.clock_h()
            n = {t: c.con.execute(f"SELECT COUNT(*) FROM {t}").fetchone()[0]
                 for t in ("actions", "samples", "particles", "temperatures", "plans", "decisions", "estimator_states")}
            pending = c.con.execute("SELECT COUNT(*) FROM samples WHERE t_h > ?", (clock + EPS_H,)).fetchone()[0]
            _, t_node, est = c.last_node()
            plan = c.latest_plan()
            dec = None if plan is None else standing_decision(c.con, plan[0])  # carried by a repeat at its time
            devs = [f"at {r[0]:g} h: {r[1]}" for r in c.con.execute("SELECT t0_h, deviation FROM actions "
                                                                     "WHERE deviation != '' ORDER BY t0_h")]
            replaced = n["decisions"] - c.con.execute("SELECT COUNT(DISTINCT plan_id) FROM decisions").fetchone()[0]
            since = None if plan is None else float(plan[1])
            warnings = c.temperature_warnings(since_h=since) + c.band_warnings(since_h=since)
    finally:
        if campaign is None:
            c.close()
    return {"folder": str(folder), "clock_h": clock, "hours": c.meta["hours"], "target": c.meta["target"],
            "counts": n, "pending_samples": pending, "estimate": est if t_node >= 0 else est,
            "latest_advice": None if plan is None else _latest_advice(plan, clock),
            "decisions_replaced": replaced,
            "decision": None if dec is None else {"accepted": bool(dec[0]), "rpm": dec[1], "milling": dec[2],
                                                  "advice_id": dec[4]},
            "deviations": devs, "warnings": warnings, "db_bytes": db.db_path(folder).stat().st_size}


def _latest_advice(plan, clock: float) -> dict:
    """``status``'s latest advice from its ``plans`` row: ``milling`` is the share of its ``interval_h``
    (as ``advise``'s ``next``; the row keeps the controller's share of its control interval)."""
    from ..loop import interval_share

    nx = json.loads(plan[5])["next"]
    h = float(nx["interval_h"])
    return {"id": plan[0], "t_h": plan[1], "rpm": plan[2],
            "milling": interval_share(plan[3], plan[4], h) if h > 0 else plan[3],
            "current": abs(plan[1] - clock) < 1e-6, **{k: nx[k] for k in ("interval_h", "mill_min", "rest_min")}}


def _not_a_campaign_file(folder, dest: Path, name: str | None) -> None:
    """Refuse an output that would replace the campaign's database (or its journal) or one of the
    input copies under ``DIR/inputs`` (later verbs check those copies and would refuse the campaign);
    the message names ``name`` first, or (``name`` None: a default path, no argument given) the file."""
    real = Path(os.path.realpath(dest))
    base = Path(os.path.realpath(folder))
    inputs = base / "inputs"
    dbfile = Path(os.path.realpath(db.db_path(folder)))
    if real == dbfile or real.name.startswith(dbfile.name) and real.parent == dbfile.parent \
            or inputs == real or inputs in real.parents:
        if name is None:
            raise InputError(f"{path_text(dest)}: the default output is the campaign's own file (its database "
                             f"or an input copy, through a link); remove it or choose another path ({arg('out')})")
        raise InputError(f"{name}: {dest} is the campaign's own file (its database or an input copy); "
                         "choose another path")


def report(folder, out=None, campaign: Campaign | None = None) -> Path:
    """Write the self-contained HTML report (default ``DIR/report.html``); returns its path.

    Parameters
    ----------
    folder : str or Path
        The campaign folder (``campaign init``'s DIR); opened read-only.
    out : str or Path, optional
        Where to write the report (not one of the campaign's own files); default ``DIR/report.html``.
    campaign : Campaign, optional
        An open campaign to read instead (the caller keeps it open).

    Returns
    -------
    Path
    """
    from .html_report import write_report

    dest = Path(out) if out else Path(folder) / "report.html"
    _not_a_campaign_file(folder, dest, arg("out") if out else None)
    c = campaign or Campaign(folder, read_only=True)
    try:
        with db.transaction(c.con, write=False, where=str(folder)):
            path = write_report(c, dest)
    finally:
        if campaign is None:
            c.close()
    return path
