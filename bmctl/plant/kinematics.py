"""Planetary-mill kinematics, shared with the moment model: see :mod:`bmctl.physics.kinematics`."""

from ..physics.kinematics import *  # noqa: F401,F403
from ..physics.kinematics import MEAN_ABS_DIFF_GAMMA15, MEAN_LOSS_RATIO, Kinematics, kinematics  # noqa: F401
