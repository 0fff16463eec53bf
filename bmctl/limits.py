"""The ranges every command and file shares (one place, so a flag and a file field agree).

Examples
--------
>>> HOURS_MIN * 3600, HOURS_MAX, RPM_MAX
(1.0, 1000.0, 2000.0)
"""

#: the shortest duration a schedule segment, a logged interval or a time flag may have: one
#: second (the plant's shortest time step is a millisecond; no mill is run for less)
HOURS_MIN = 1.0 / 3600.0
#: the longest batch: 1,000 h of milling (the longest mechanical-alloying runs reported are ~500 h)
HOURS_MAX = 1000.0
#: sun-disc speeds of laboratory planetary mills reach ~1,100 rpm (Fritsch P-7 premium); 2,000 is
#: a hard physical ceiling for the kinematics (Burgio) as implemented
RPM_MAX = 2000.0
#: a mill or rest phase of a cycle, in minutes: 6 s to a day
PHASE_MIN_MINUTES, PHASE_MAX_MINUTES = 0.1, 1440.0

#: ball-to-powder mass ratios a card may hold (mechanical alloying uses 1:1 to 100:1)
BALL_TO_POWDER_RANGE = (1.0, 100.0)

#: rounding allowed on a control input or interval handed to an estimator or the loop (a solver's bound
#: violation, a difference of times): within it a value is taken as it was, beyond it refused
INPUT_ROUNDING = 1e-6


def rpm_rounding(rpm_max: float) -> float:
    """The rounding allowed on an rpm against the limit ``rpm_max``: :data:`INPUT_ROUNDING`
    of the limit (a solver works on rpm / rpm_max), at least INPUT_ROUNDING rpm.

    >>> rpm_rounding(600.0), rpm_rounding(0.5)
    (0.0006, 1e-06)
    """
    return INPUT_ROUNDING * max(1.0, float(rpm_max))


def is_rpm_milling(u) -> bool:
    """Whether ``u`` is one control input (rpm, milling): finite, rpm >= 0 and milling in [0, 1], each
    within :data:`INPUT_ROUNDING`.

    >>> is_rpm_milling((300.0, 1.0 + 1e-9)), is_rpm_milling((300.0, 2.0)), is_rpm_milling(300.0)
    (True, False, False)
    """
    import numpy as np

    try:
        uu = np.asarray(u, dtype=float)
    except (TypeError, ValueError):
        return False
    tol = INPUT_ROUNDING
    return bool(uu.shape == (2,) and np.all(np.isfinite(uu)) and uu[0] >= -tol and -tol <= uu[1] <= 1 + tol)
