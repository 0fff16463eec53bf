"""Controllers on the moment model: MPC (casadi/IPOPT), an LQR baseline and open-loop recipes.

All share one interface (docs/control.md)::

    from bmctl.control import make_controller
    ctrl = make_controller("controllers/mpc-default.toml", model)
    plan = ctrl.plan(x_est, t_h, p=None, u_prev=None)   # -> Plan
    rpm, milling = plan.u_apply                          # for ctrl.interval_h hours
"""

from __future__ import annotations

from pathlib import Path

from .base import Plan, Reference, Status, applied_input, peak_temperature, schedule_segments
from .config import (TARGET_KEYS, LQRConfig, MPCConfig, RecipeConfig, load_controller, parse_target,
                     validate_controller)

__all__ = ["make_controller", "Plan", "Status", "Reference", "applied_input", "peak_temperature",
           "schedule_segments", "load_controller", "validate_controller", "parse_target", "MPCConfig",
           "LQRConfig", "RecipeConfig", "TARGET_KEYS"]


def make_controller(config, model, target=None):
    """Build a controller from a config file, a validated config or a dict.

    Parameters
    ----------
    config : path-like, MPCConfig, LQRConfig, RecipeConfig or dict
        ``controllers/*.toml``; its ``kind`` picks the class.
    model : MomentModel
        The prediction model (``bmctl.moments.make_moment_model``).
    target : optional
        Overrides the config's target (see ``set_target``).

    Returns
    -------
    PlanController, MPCController, LQRController or RecipeController
        (an MPC file with ``[plan] method = "search"`` gives a PlanController)
        Each has ``interval_h``, ``t_end_h``, ``plan(x_est, t_h, p=None, u_prev=None) -> Plan``,
        ``set_target(target, t_end_h=None)`` and ``reset()``.

    Examples
    --------
    >>> from bmctl.control import make_controller
    >>> from bmctl.moments import make_moment_model
    >>> model = make_moment_model("models/alni-1to1-300rpm-lab.toml")
    >>> ctrl = make_controller("controllers/recipe-300rpm-continuous.toml", model)
    >>> plan = ctrl.plan(model.x0(), 0.0)
    >>> plan.u_apply.tolist()
    [300.0, 1.0]
    """
    if not (hasattr(model, "x0") and hasattr(model, "rpm_max")):  # None gave an AttributeError deep inside
        raise TypeError(f"model: must be a moment model (bmctl.moments.make_moment_model), got {type(model).__name__}")
    if isinstance(config, (str, Path)):
        cfg = load_controller(config)
    elif isinstance(config, dict):
        cfg = validate_controller(config, "controller")
    else:
        cfg = config
    if isinstance(cfg, MPCConfig) and cfg.plan.method == "search":
        from .planner import PlanController

        return PlanController(cfg, model, target)
    if isinstance(cfg, MPCConfig):
        from .mpc import MPCController

        return MPCController(cfg, model, target)
    if isinstance(cfg, LQRConfig):
        from .baselines import LQRController

        return LQRController(cfg, model, target)
    if isinstance(cfg, RecipeConfig):
        from .baselines import RecipeController

        return RecipeController(cfg, model, target)
    raise TypeError(f"make_controller: unsupported config {type(cfg).__name__}")
