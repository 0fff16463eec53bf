"""Is a target reachable under the mill's limits? The closest reachable state and the binding constraint.

:func:`reachability` solves the phase-pattern design (:mod:`bmctl.control.pattern`) for the
smallest target error alone (no energy or time cost) over the whole batch. When that error
exceeds the tolerance the target is out of reach; the answer names the closest reachable
outputs and the limits active at that optimum (:meth:`PatternDesigner.active`): the
temperature ceiling, the rpm maximum, the minimum milling period or rest, the switch budget
and the batch time (every phase milling throughout: more hours would be needed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Reach:
    """Answer of :func:`reachability`.

    Attributes
    ----------
    reachable : bool
    error : float
        Smallest largest relative target error found (0 inside a window).
    closest : dict
        Target quantities at that optimum (moments and D-values).
    binding : list of str
        Active limits, e.g. "temperature ceiling", "rpm max", "minimum milling period (5 min)",
        "switch budget (36)", "batch time" (empty when reachable).
    """

    reachable: bool
    error: float
    closest: dict
    binding: list

    def line(self, target: dict) -> str:
        from .config import format_target

        got = ", ".join(f"{k} {self.closest[k]:.4g} (target {format_target(v)})" for k, v in target.items())
        lim = ", ".join(self.binding) if self.binding else "none identified"
        return f"target out of reach (error {100 * self.error:.1f} %): closest {got}; binding: {lim}"


def reachability(model, target: dict, hours: float, cfg, p=None, result=None) -> Reach:
    """Check a target against the mill's limits over a batch of ``hours`` from the card's initial state.

    Parameters
    ----------
    model : MomentModel
    target : dict
        {key: point or (lo, hi)}.
    hours : float
    cfg : MPCConfig
        Bounds, ceiling, mill limits, ``objective.tolerance``.
    p : array_like, optional
    result : PatternResult, optional
        A design already solved for this target and batch (its error is reused when within tolerance).
    """
    from .pattern import PatternDesigner

    tol = cfg.objective.tolerance
    if result is not None and result.error <= tol:
        return Reach(True, result.error, result.outputs, [])
    d = PatternDesigner(model, hours, cfg, target, p, energy_weight=0.0)
    r = d.solve("relax-round")
    if result is not None and result.error < r.error:
        r = result
    if r.error <= tol:
        return Reach(True, r.error, r.outputs, [])
    binding = list(r.active)
    return Reach(False, r.error, r.outputs, binding)
