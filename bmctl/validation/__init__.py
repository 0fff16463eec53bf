"""Validation and verification scaffolding, kept out of the core package's loop.

* :mod:`.exact`, :mod:`.cases`, :mod:`.engine`, :mod:`.report` -- verification of the plant's
  population Monte Carlo engine (``bmctl verify``, docs/verification.md);
* :mod:`.study` -- the particle filter's estimation study on synthetic plant truth;
* :mod:`.measure` -- the measurement path against synthetic micrographs with known truth.

``from bmctl.validation import verify`` gives the verification's public names in one namespace.
"""
