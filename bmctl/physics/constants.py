"""Named constants shared across the plant, the moment model, the estimator and the controllers.

One source of truth per number; a module that needs one imports it from here.
"""

from __future__ import annotations

#: r is kept in [0, R_MAX] (r -> 1 is a fractal boundary, eqn 3)
R_MAX = 0.99
#: time comparisons (h): two batch times closer than this are the same instant
TIME_EPS_H = 1e-9
#: generic positive floor of a denominator or a clipped rate (dimensionless)
TINY = 1e-9

#: E|X - Y| for X, Y iid Gamma(3/2, 1) (= 4/pi up to quadrature error): mean energy lost per
#: collision in units of the Gamma scale (eqn 5). The value is the nested-quadrature result
#: (:func:`bmctl.physics.kinematics.abs_diff_mean`); tests/physics recomputes it.
MEAN_ABS_DIFF_GAMMA15 = 1.2732395447351692
#: E[(max - min) / max] of two iid Gamma(3/2) draws (scale-free): the share of particles one
#: collision processes (eqn 5, docs/model.md Sec. 3.2); :func:`bmctl.physics.kinematics.loss_ratio_mean`.
MEAN_LOSS_RATIO = 0.5464790894702789
