"""The moment model: size and shape moments, vial temperature and hardening as a smooth ODE.

One definition (:mod:`bmctl.moments.equations`) evaluates with numpy and casadi. See
docs/moments.md.

>>> from bmctl.moments import for_card
>>> model = for_card("models/alni-1to1-300rpm-lab.toml")  # refuses coefficients of another card  # doctest: +SKIP
"""

from .forcard import for_card
from .model import INPUT_NAMES, PARAM_NAMES, STATE_NAMES, MomentModel, default_coeffs, make_moment_model

__all__ = ["for_card", "MomentModel", "make_moment_model", "default_coeffs", "STATE_NAMES", "INPUT_NAMES", "PARAM_NAMES"]
