"""Vial temperature, softening and hardening, shared with the moment model: see :mod:`bmctl.physics.thermal`."""

from ..physics.thermal import *  # noqa: F401,F403
