"""What a vial-temperature reading says at once: above the ceiling, or far from the estimate.

``campaign log`` stores each reading's check with the estimator node of its time (the
reading, and the estimate's mean and std just before it); :func:`reading_warnings` turns a
node into one-line warnings, which ``log`` prints at once and the next ``advise`` repeats.
"""

from __future__ import annotations

import math

#: a reading this many standard deviations (reading noise and estimate spread together) from the
#: estimate just before it is "far from the estimate"
FAR_Z = 3.0
#: an estimate this certain (std, degC) of the vial's temperature, and within a reading's noise of the
#: card's room temperature, is the room: the vial has rested (or barely milled), so its heating, which the
#: filter learns, does not enter it (before the first reading a milling vial is as certain, far above it)
AT_AMBIENT_SD_C = 0.2


def reading_warnings(est: dict, ceiling_c: float | None, sigma_reading_c: float,
                     ambient_c: float | None = None) -> list[str]:
    """One-line warnings for the reading weighed in at the estimator node ``est`` (none without one).

    Parameters
    ----------
    est : dict
        An estimate dict of the campaign's timeline (``reading_c``, ``reading_predicted_c``,
        ``reading_predicted_sd_c`` where a reading was weighed in; ``t_h``).
    ceiling_c : float or None
        The campaign's vial-temperature ceiling (degC).
    sigma_reading_c : float
        The stated noise of a reading (degC).
    ambient_c : float, optional
        The card's room temperature (``thermal.ambient_C``): a far reading of a certain estimate names
        it only when the estimate is within ``sigma_reading_c`` of it (None: on the certainty alone).

    Returns
    -------
    list of str

    Examples
    --------
    >>> est = {"t_h": 1.0, "reading_c": 75.0, "reading_predicted_c": 58.0, "reading_predicted_sd_c": 1.0}
    >>> for w in reading_warnings(est, 60.0, 2.0):
    ...     print(w)
    reading 75 °C at 1 h is above the ceiling (60 °C)
    reading 75 °C at 1 h is far from the estimate just before it (58.0 ± 1.0 °C; 7.6 σ with the reading's 2 °C)
    >>> rested = {"t_h": 0.5, "reading_c": 15.0, "reading_predicted_c": 25.0, "reading_predicted_sd_c": 0.0}
    >>> print(reading_warnings(rested, 80.0, 2.0)[0])  # doctest: +ELLIPSIS
    reading 15 °C at 0.5 h is far from ... (25.0 ± 0.0 °C; 5.0 σ ...); the estimate is the card's room temperature: ...
    >>> milled = {"t_h": 0.5, "reading_c": 59.3, "reading_predicted_c": 71.7, "reading_predicted_sd_c": 0.0}
    >>> print(reading_warnings(milled, 80.0, 2.0, ambient_c=25.0)[0])  # a sure estimate far above the room
    reading 59.3 °C at 0.5 h is far from the estimate just before it (71.7 ± 0.0 °C; 6.2 σ with the reading's 2 °C)
    """
    y = est.get("reading_c")
    if y is None:
        return []
    out = []
    t = est.get("t_h", math.nan)
    if ceiling_c is not None and y > ceiling_c:
        out.append(f"reading {y:g} °C at {t:g} h is above the ceiling ({ceiling_c:g} °C)")
    m, sd = est.get("reading_predicted_c", math.nan), est.get("reading_predicted_sd_c", math.nan)
    if math.isfinite(m) and math.isfinite(sd):
        z = abs(y - m) / math.hypot(sd, sigma_reading_c)
        if z > FAR_Z:
            line = (f"reading {y:g} °C at {t:g} h is far from the estimate just before it ({m:.1f} ± {sd:.1f} °C; "
                    f"{z:.1f} σ with the reading's {sigma_reading_c:g} °C)")
            rested = ambient_c is None or abs(m - ambient_c) <= sigma_reading_c
            if sd < AT_AMBIENT_SD_C and rested:  # a rested vial: the room, not the heating, is off
                line += (f"; the estimate is the card's room temperature: if the mill's room is at another, set "
                         "thermal.ambient_C in the card (the filter learns how strongly the mill heats, not the room's "
                         "temperature)")
            out.append(line)
    return out


def estimate_warning(est: dict, ceiling_c: float | None) -> list[str]:
    """A warning when the estimated vial temperature's 95 % quantile is above the ceiling.

    Examples
    --------
    >>> estimate_warning({"t_h": 2.0, "temperature_c": 74.2, "temperature_c_q05": 70.8,
    ...                   "temperature_c_q95": 77.7}, 60.0)
    ['estimated vial temperature at 2 h: 74.2 [70.8, 77.7] °C, above the ceiling (60 °C)']
    """
    if ceiling_c is None or est.get("temperature_c_q95", -math.inf) <= ceiling_c:
        return []
    return [f"estimated vial temperature at {est['t_h']:g} h: {est['temperature_c']:.1f} "
            f"[{est['temperature_c_q05']:.1f}, {est['temperature_c_q95']:.1f}] °C, above the ceiling ({ceiling_c:g} °C)"]


def _minutes_text(m: float) -> str:
    """Minutes as an operator reads them: whole when within 3 s of a whole minute, else 0.1 min
    (two figures under a minute)."""
    if abs(m - round(m)) < 0.05 and (round(m) > 0 or m <= 0):  # a few seconds of milling are not 0 min
        return f"{round(m)}"
    return f"{m:.2g}" if m < 1 else f"{m:.1f}"


def interval_text(rpm: float, milling: float, hours: float) -> str:
    """A logged interval in words: ``rest 30 min`` or ``300 rpm, mill 20 min, rest 10 min`` (milling
    first); a share of a minute is shown, not rounded to a rest.

    Examples
    --------
    >>> interval_text(300.0, 0.001, 0.5)
    '300 rpm, mill 0.03 min, rest 30 min'
    >>> interval_text(300.0, 0.995, 0.5)
    '300 rpm, mill 29.9 min, rest 0.15 min'
    >>> interval_text(0.0, 0.0, 0.5), interval_text(250.0, 2 / 3, 0.5)
    ('rest 30 min', '250 rpm, mill 20 min, rest 10 min')
    """
    total = hours * 60.0
    mill = milling * total if rpm > 0 else 0.0
    if mill <= 0:
        return f"rest {_minutes_text(total)} min"
    return f"{rpm:g} rpm, mill {_minutes_text(mill)} min, rest {_minutes_text(total - mill)} min"
