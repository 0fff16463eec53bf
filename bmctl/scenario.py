"""Closed-loop trial scenarios (``scenarios/trial-*.toml``): typed, validated, one-line errors."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from .config import HOURS, Range, Strict, load
from .errors import InputError
from .physics.constants import TIME_EPS_H

TARGET_KEYS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "d50_um", "d90_um", "span")  # = control.config.TARGET_KEYS


class ScenarioInfo(Strict):
    name: str
    description: str  # one line: what the scenario shows


class PlantSpec(Strict):
    """The truth: a stochastic plant, possibly with gamma/delta off the controller's card."""

    model: str | None = None  # default: the scenario's model card
    particles: Annotated[int, Field(ge=100, le=1_000_000)] = 5000
    # gamma, delta off the card by a factor: the filter's parameter walk covers ~[0.05, 20]
    gamma_factor: Range(0.01, 100.0) = 1.0
    delta_factor: Range(0.01, 100.0) = 1.0


class SamplingSpec(Strict):
    """Micrograph sampling (multi-rate: every_h may be longer than the control interval)."""

    every_h: Range(1 / 60, 1000.0) = 1.0
    particles: Annotated[int, Field(ge=5, le=100_000)] = 300
    um_per_px: Range(1e-4, 1e3) | None = 1.0  # as --um-per-px (bmctl.measure.scale.check_scale)
    noise: Range(0.0, 1.0) = 0.03  # relative measurement noise (fast path only: refused with render = true)
    render: bool = False  # the renderer and the real segmentation (their own noise) instead of the fast path
    temperature_reading: bool = True
    feed: bool = False  # also sample the feed at 0 h, before the first decision (campaign: sample --at-h 0)


class EstimatorSpec(Strict):
    """``[estimator]``: which estimator, its particles, and optionally every one of its settings
    (``[estimator.pf]``: :class:`bmctl.estimate.FilterSettings`; ``[estimator.ukf]``:
    :class:`bmctl.estimate.ukf.UKFSettings`)."""

    kind: Literal["pf", "ukf"] = "pf"  # particle filter or unscented Kalman filter (particles: pf only)
    particles: Annotated[int, Field(ge=50, le=200_000)] = 1000
    pf: dict = {}  # particle-filter settings (validated as FilterSettings; n_particles comes from `particles`)
    ukf: dict = {}  # UKF settings (validated as UKFSettings)

    @model_validator(mode="after")
    def _settings_valid(self):
        from pydantic import ValidationError

        from .config import unknown_key_message

        other = "ukf" if self.kind == "pf" else "pf"
        if getattr(self, other):  # settings of the estimator not chosen would be ignored without a word
            raise ValueError(f"{other}: settings of the {other} estimator, but estimator.kind is {self.kind!r}")
        if self.kind == "ukf" and "particles" in self.model_fields_set:  # a count the UKF would ignore
            raise ValueError("particles: a particle count, but estimator.kind is 'ukf' (sigma points, no particles)")
        try:
            settings = self.filter_settings()
        except ValidationError as exc:
            errs = exc.errors()
            err = next((e for e in errs if e["type"] == "extra_forbidden"), errs[0])
            where = ".".join(str(x) for x in err["loc"])
            if err["type"] == "extra_forbidden":  # a typo: name the close setting
                from .estimate import FilterSettings
                from .estimate.ukf import UKFSettings

                known = (UKFSettings if self.kind == "ukf" else FilterSettings).model_fields
                raise ValueError(f"{self.kind}.{where}: {unknown_key_message(str(err['loc'][-1]), known)}") from None
            raise ValueError(f"{self.kind}.{where}: {err['msg']}") from None
        del settings
        return self

    def filter_settings(self):
        """The chosen estimator's settings of this table."""
        if self.kind == "ukf":
            from .estimate.ukf import UKFSettings

            return UKFSettings(**self.ukf)
        from .estimate import FilterSettings

        if "n_particles" in self.pf:
            raise ValueError("pf.n_particles: give the particle count as estimator.particles")
        return FilterSettings(n_particles=self.particles, **self.pf)


class ControllerSpec(Strict):
    config: str  # controllers/*.toml; its `kind` (mpc, lqr, recipe) picks the controller


class Scenario(Strict):
    """A closed-loop (or open-loop recipe) trial."""

    scenario: ScenarioInfo
    model: str  # the controller's and estimator's model card
    hours: HOURS = 12.0
    temperature_max_c: Range(0.0, 4000.0, lo_open=True) | None = None  # vial ceiling: overrides the controller's, counts violations
    target: dict[str, Annotated[float, Field(gt=0)] | list[Annotated[float, Field(gt=0)]]] = {}  # a number or a window [lo, hi]
    plant: PlantSpec = PlantSpec()
    sampling: SamplingSpec = SamplingSpec()
    estimator: EstimatorSpec = EstimatorSpec()
    controller: ControllerSpec

    @model_validator(mode="after")
    def _check(self):
        from .control.config import check_dvalue_order, target_value_problem

        if self.sampling.render and "noise" in self.sampling.model_fields_set:  # the rendered path has no noise knob
            raise ValueError("sampling.noise: used only without render (the fast path's segmentation noise); "
                             "with render = true the rendered micrograph's segmentation sets the scatter: "
                             "leave noise out or set render = false")
        for k in self.target:
            if k not in TARGET_KEYS:
                from .config import did_you_mean

                raise ValueError(f"target.{k}: unknown target{did_you_mean(k, TARGET_KEYS)}; choose from "
                                 f"{', '.join(TARGET_KEYS)}")
            v = self.target[k]
            if isinstance(v, list):
                if len(v) != 2 or v[0] > v[1]:
                    raise ValueError(f"target.{k}: a window is [lo, hi] with lo <= hi (got {v})")
                self.target[k] = (float(v[0]), float(v[1])) if v[1] > v[0] else float(v[0])
            problem = target_value_problem(k, self.target[k])  # each key's range, as the controllers take it
            if problem is not None:
                raise ValueError(f"target.{k}: {problem}")
        try:
            check_dvalue_order(self.target, "target")
        except InputError as exc:
            raise ValueError(str(exc)) from None
        return self


def resolve(path: str, base: Path) -> Path:
    """A path from a scenario: next to the scenario, else relative to the scenario folder's parent
    (the project root), else as given (from the working directory). The scenario's own folder comes
    first, so the same scenario runs the same files from any working directory."""
    p = Path(path)
    for cand in (base / p, base.parent / p, p):
        if cand.exists():
            return cand
    raise InputError(f"{path}: file not found (looked in {base}, {base.parent}, .)")


def load_scenario(path: str | Path, campaign: bool = False) -> Scenario:
    """Load and validate a scenario TOML; referenced files must exist.

    Parameters
    ----------
    path : path-like
        The scenario TOML.
    campaign : bool, optional
        The trial runs through the campaign verbs (``bmctl trial --campaign``): what a campaign
        cannot reproduce (:func:`bmctl.campaign.simulated.check_scenario`) is refused first.

    Returns
    -------
    Scenario
    """
    sc = load(Scenario, path)
    if campaign:
        from .campaign.simulated import check_scenario

        check_scenario(sc, path)
    base = Path(path).resolve().parent
    for ref in (sc.model, sc.plant.model, sc.controller.config):
        if ref is not None:
            try:
                resolve(ref, base)
            except InputError as exc:
                raise InputError(f"{path}: {exc}") from None
    from .control.config import check_dwell_interval, check_lqr_track, load_controller
    from .control.design import check_batch

    cfg_path = resolve(sc.controller.config, base)
    cfg = load_controller(cfg_path)
    check_dwell_interval(cfg, str(cfg_path))
    # as `bmctl design --hours`: a batch under the mill's minimum milling period (or 5 min) is not a schedule
    check_batch(sc.hours, cfg, "target", f"{path}: hours", str(cfg_path))
    interval_h = cfg.interval_h if cfg.interval_h is not None else (
        (cfg.mill_min + cfg.rest_min) / 60.0 if getattr(cfg, "mill_min", None) is not None else 0.5)
    interval_h = min(interval_h, sc.hours)  # a batch shorter than one interval is one interval
    if sc.sampling.every_h < interval_h - TIME_EPS_H:  # the loop samples at interval ends, at most once each
        given = "sampling.every_h" if "every_h" in sc.sampling.model_fields_set else "sampling.every_h (default)"
        raise InputError(f"{path}: {given}: {sc.sampling.every_h:g} h is shorter than the control interval "
                         f"({interval_h:g} h, {cfg_path}): a trial samples at the end of each interval, at most "
                         f"once; give every_h >= {interval_h:g}")
    if sc.temperature_max_c is not None:  # named here, with the file (the trial checks the controller's own)
        from .config import load_card

        ambient = load_card(resolve(sc.model, base)).thermal.ambient_C
        if sc.temperature_max_c <= ambient:
            raise InputError(f"{path}: temperature_max_c: {sc.temperature_max_c:g} °C is not above the card's ambient "
                             f"temperature (thermal.ambient_C = {ambient:g} °C): a resting vial is already at the ambient")
    if cfg.kind != "recipe" and not sc.target:
        raise InputError(f"{path}: target: a feedback controller ({cfg.kind}) needs at least one target")
    if cfg.kind == "lqr":  # a target the LQR cannot track: refused before the trial writes anything
        check_lqr_track(cfg.lqr.track, sc.target, f"{path}: target", str(cfg_path))
    return sc
