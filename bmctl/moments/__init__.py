"""The moment model: size and shape moments, vial temperature and hardening as a smooth ODE.

One definition (:mod:`bmctl.moments.equations`) evaluates with numpy and casadi. See
docs/moments.md.

>>> from bmctl.moments import make_moment_model
>>> model = make_moment_model("models/alni-1to1-300rpm-lab.toml")  # doctest: +SKIP
"""

from .model import INPUT_NAMES, PARAM_NAMES, STATE_NAMES, MomentModel, default_coeffs, make_moment_model

__all__ = ["MomentModel", "make_moment_model", "default_coeffs", "STATE_NAMES", "INPUT_NAMES", "PARAM_NAMES"]
