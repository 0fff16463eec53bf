"""Calibrate card parameters from measured micrograph series, the stochastic plant as simulator.

- :mod:`.history`: history files (schedule + samples) and their loader
- :mod:`.params`: named card parameters (alpha, beta, gamma, delta, section.field)
- :mod:`.simulate`: the plant as the simulator of a history; the summaries compared
- :mod:`.moment_start`: the moment model's maximum-likelihood start for gamma, delta
- :mod:`.fit`: synthetic-likelihood Gauss-Newton fit, intervals, identifiability
- :mod:`.outputs`: calibrated card, calibration.json, figures

See docs/calibration-from-data.md.
"""
