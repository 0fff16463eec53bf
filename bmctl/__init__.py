"""bmctl: closed-loop control and optimisation of ball milling.

Plant (the stochastic model of size s and aspect ratio r), moment model, micrograph
measurement, particle filter and MPC, each behind one small interface.
"""

__version__ = "0.1.0"
