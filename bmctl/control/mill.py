"""The mill's limits on an applied input: dwell times, rpm steps, a minimum rpm and a switch budget.

An interval of a controller's plan is applied as ``milling * interval_h`` of milling at ``rpm``,
then a rest. :func:`enforce` turns a planned (rpm, milling) into one the mill can run:

* rpm a multiple of ``rpm_step`` (nearest, never above the cap) and >= ``rpm_min_milling``;
* a milling period within the interval is either absent or >= ``min_mill_min``, and the rest
  either absent or >= ``min_rest_min`` (whole minutes); then every merged milling period and rest
  of the applied sequence respects the dwell times, whatever the neighbouring intervals hold;
* the on/off transitions the interval adds (a change of state at its start, and the
  mill-to-rest switch inside it) fit the batch's remaining ``max_switches``; otherwise the
  interval keeps the state the previous one ended in (milling, unless the temperature cap
  forbids it, then rest).
"""

from __future__ import annotations

import math

import numpy as np


def round_rpm(rpm: float, mill, rpm_cap: float) -> float:
    """rpm on the mill's step (nearest; the largest step <= ``rpm_cap`` when above it), >= rpm_min_milling.

    Parameters
    ----------
    rpm : float
        Planned rpm.
    mill : Mill
        The mill's limits.
    rpm_cap : float
        Highest allowed rpm.
    """
    r = max(float(rpm), mill.rpm_min_milling)
    if mill.rpm_step:
        st = mill.rpm_step
        r = round(r / st) * st
        if r > rpm_cap + 1e-9:
            r = math.floor(rpm_cap / st + 1e-9) * st
        if r < mill.rpm_min_milling - 1e-9:
            r = math.ceil(mill.rpm_min_milling / st - 1e-9) * st
    return float(min(r, rpm_cap)) if not mill.rpm_step else float(r)


def dwell_minutes(mill_min: float, interval_min: float, mill) -> float:
    """Milling minutes of one interval with the dwell limits: 0, >= min_mill_min, and a rest of 0 or >= min_rest_min.

    Parameters
    ----------
    mill_min : float
        Planned milling minutes in the interval.
    interval_min : float
        Interval length (min).
    mill : Mill
    """
    a = float(np.clip(round(mill_min), 0.0, interval_min))
    lo, rlo = mill.min_mill_min, mill.min_rest_min
    feasible = [0.0, float(interval_min)]
    hi_partial = interval_min - max(rlo, 1.0)
    lo_partial = max(lo, 1.0)
    if lo_partial <= hi_partial:
        feasible.append(float(np.clip(a, math.ceil(lo_partial), math.floor(hi_partial))))
    return min(feasible, key=lambda v: (abs(v - a), -v))


def transitions(prev_end_milling: bool | None, milling: float) -> int:
    """On/off transitions an interval (mill ``milling``, then rest) adds after one that ended milling or not."""
    if milling <= 0:
        return int(prev_end_milling is True)
    n = 0 if prev_end_milling in (None, True) else 1
    if milling < 1.0:
        n += 1
    return n


class MillGuard:
    """Applies :func:`enforce` over a batch: remembers how the last interval ended and the switches used.

    Parameters
    ----------
    mill : Mill
    interval_h : float
    """

    def __init__(self, mill, interval_h: float):
        self.mill = mill
        self.interval_h = float(interval_h)
        self.reset()

    def reset(self) -> None:
        self.switches = 0
        self.end_milling: bool | None = None
        self.t_h: float | None = None

    def get_state(self) -> dict:
        """Switch count and the last applied interval's end, as plain data."""
        return {"switches": self.switches, "end_milling": self.end_milling, "t_h": self.t_h}

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state`."""
        self.switches = int(state["switches"])
        self.end_milling = None if state["end_milling"] is None else bool(state["end_milling"])
        self.t_h = None if state["t_h"] is None else float(state["t_h"])

    def active(self) -> bool:
        m = self.mill
        return bool(m.min_mill_min or m.min_rest_min or m.max_switches is not None or m.rpm_min_milling or m.rpm_step)

    def enforce(self, u, t_h: float, rpm_cap: float, m_cap: float = 1.0, commit: bool = True) -> tuple[np.ndarray, str]:
        """The applied (rpm, milling) for the interval starting at ``t_h`` and a note when it differs.

        Parameters
        ----------
        u : sequence of 2 floats
            Planned (rpm, milling) (already rounded to whole minutes or not).
        t_h : float
            Batch time of the interval start (a time at or before the last one restarts the count).
        rpm_cap : float
            Highest rpm allowed now.
        m_cap : float
            Largest milling fraction allowed now (temperature cap, batch end).
        commit : bool
            Update the switch count and end state.
        """
        if self.t_h is not None and t_h <= self.t_h - 1e-9:
            self.reset()
        mill, dt_min = self.mill, self.interval_h * 60.0
        rpm, m = float(u[0]), float(np.clip(u[1], 0.0, 1.0))
        if rpm <= 0:
            m = 0.0
        minutes = dwell_minutes(m * dt_min, dt_min, mill) if m > 0 else 0.0
        cap_min = math.floor(m_cap * dt_min + 1e-9)
        if minutes > cap_min:
            minutes = dwell_minutes(min(minutes, cap_min), dt_min, mill)
            if minutes > cap_min:
                minutes = 0.0
        m2 = minutes / dt_min
        note = []
        if mill.max_switches is not None:
            left = mill.max_switches - self.switches
            if transitions(self.end_milling, m2) > left:
                keep = 1.0 if self.end_milling else 0.0
                if keep > 0 and cap_min < dt_min:
                    keep = 0.0
                options = [v for v in (keep, 0.0, 1.0 if cap_min >= dt_min else None)
                           if v is not None and transitions(self.end_milling, v) <= left]
                m2 = options[0] if options else 0.0
                note.append(f"switch budget ({mill.max_switches}) spent: milling {m:.2f} -> {m2:.2f}")
        if m2 > 0:
            r2 = round_rpm(rpm, mill, rpm_cap)
            if r2 <= 0:
                m2 = 0.0
        else:
            r2 = 0.0
        if abs(m2 - m) > 0.5 / dt_min and not note:
            note.append(f"dwell limits: milling {m * dt_min:.0f} -> {m2 * dt_min:.0f} min")
        if commit:
            self.switches += transitions(self.end_milling, m2)
            if m2 > 0 or self.end_milling is not None:
                self.end_milling = m2 >= 1.0 if m2 > 0 else False
            self.t_h = float(t_h)
        return np.array([r2, m2]) if m2 > 0 else np.array([0.0, 0.0]), "; ".join(note)


def count_switches(segments) -> int:
    """On/off transitions of a schedule of (hours, rpm) segments (rpm 0 = rest)."""
    states = [r > 0 for h, r in segments if h > 1e-12]
    return int(sum(a != b for a, b in zip(states, states[1:])))


def check_schedule(segments, mill, tol_min: float = 1e-6, switches: int | None = None) -> list[str]:
    """Violations of the mill's limits by a schedule of (hours, rpm) segments (empty when it complies),
    the switch budget first.

    The last segment may be shorter than the dwell minimum only if it is the batch's end.
    ``switches``: the schedule's on/off switches as the budget counts them (default
    :func:`count_switches` of the segments; a design passes its count over the batch).
    """
    n = count_switches(segments) if switches is None else int(switches)
    out = []
    if mill.max_switches is not None and n > mill.max_switches:
        out.append(f"{n} on/off switches > max_switches {mill.max_switches}")
    merged: list[list[float]] = []
    for h, r in segments:
        on = r > 0
        if merged and (merged[-1][1] > 0) == on and (not on or abs(merged[-1][1] - r) < 1e-9 or True):
            merged[-1][0] += h
        else:
            merged.append([h, r])
    for i, (h, r) in enumerate(merged):
        last = i == len(merged) - 1
        lim = mill.min_mill_min if r > 0 else mill.min_rest_min
        if h * 60.0 < lim - tol_min and not last:
            out.append(f"segment {i}: {'milling' if r > 0 else 'rest'} {h * 60:.1f} min < {lim:g} min")
    for h, r in segments:
        if r > 0 and mill.rpm_step and abs(r / mill.rpm_step - round(r / mill.rpm_step)) > 1e-6:
            out.append(f"rpm {r:g} not a multiple of {mill.rpm_step:g}")
        if r > 0 and r < mill.rpm_min_milling - 1e-9:
            out.append(f"rpm {r:g} below {mill.rpm_min_milling:g}")
    return out
