"""Verification of the plant's population Monte Carlo engine (``bmctl verify``): every public
name of :mod:`.exact`, :mod:`.cases`, :mod:`.engine` and :mod:`.report` in one namespace."""

from .cases import *  # noqa: F401,F403
from .engine import *  # noqa: F401,F403
from .exact import *  # noqa: F401,F403
from .report import *  # noqa: F401,F403
