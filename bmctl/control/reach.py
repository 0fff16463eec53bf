"""Is a target reachable under the mill's limits? The closest reachable state and the binding constraint.

:func:`reachability` designs the batch (:func:`bmctl.control.design.design_one`: the global search
over operable schedule families, then the phase-pattern NLP started from its best schedules).
When neither comes within the tolerance the target is out of reach; the answer names the closest
outputs, the limits active at that schedule (the temperature ceiling, the rpm maximum, the minimum
milling period or rest, the switch budget, the batch time: milling throughout) and the search's
best schedule of each family, so the user sees why.
"""

from __future__ import annotations

from dataclasses import dataclass, field


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
        Active limits, e.g. "vial-temperature ceiling (80 °C) from 2 h", "rpm at its upper bound
        (500 rpm) from 0 h", "minimum milling period (5 min)",
        "switch budget (36 of 36 over the batch with this plan)",
        "batch time: milling throughout to the batch end" (empty when reachable).
    per_family : dict
        The global search's best schedule per family: {family: {"error", "peak_c", "schedule", ...}}.
    """

    reachable: bool
    error: float
    closest: dict
    binding: list
    per_family: dict = field(default_factory=dict)

    def line(self, target: dict) -> str:
        from .config import format_target

        got = ", ".join(f"{k} {self.closest[k]:.4g} (target {format_target(v)})" for k, v in target.items())
        lim = ", ".join(self.binding) if self.binding else "none identified"
        return f"target out of reach (error {100 * self.error:.1f} %): closest {got}; binding: {lim}"

    def family_lines(self) -> list[str]:
        """One line per schedule family: its best schedule, error and peak temperature."""
        out = []
        for f, v in self.per_family.items():
            out.append(f"  {f:<10} error {100 * v['error']:6.1f} %  peak {v['peak_c']:5.1f} °C  "
                       f"{v['switches']:2d} switches  {v['schedule']}")
        return out


def reachability(model, target: dict, hours: float, cfg, p=None, result=None) -> Reach:
    """Check a target against the mill's limits over a batch of ``hours`` from the card's initial state.

    Parameters
    ----------
    model : MomentModel
    target : dict
        {key: point or (lo, hi)}.
    hours : float
    cfg : MPCConfig
        Bounds, ceiling, mill limits, ``objective.tolerance``, ``[plan]``.
    p : array_like, optional
    result : PatternResult, optional
        A design already made for this target and batch: reused when within the tolerance.
    """
    from .design import design_one

    tol = cfg.objective.tolerance
    if result is not None and result.error <= tol:
        return Reach(True, result.error, result.outputs, [])
    best, local, sr, _ = design_one(model, target, hours, cfg, p)
    if result is not None and result.error < best.error:
        best = result
    if best.error <= tol:
        return Reach(True, best.error, best.outputs, [], sr.per_family)
    return Reach(False, best.error, best.outputs, list(best.active), sr.per_family)
