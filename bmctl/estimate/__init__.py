"""State and parameter estimation from micrograph samples: likelihood, resampling, particle filter, UKF.

See docs/estimation.md. The filter (:class:`ParticleFilter`) runs the moment model between
samples and weighs its particles by the likelihood of each measured sample
(:func:`loglik_raster`) under the laws the state implies, with the misspecification handled
explicitly (measurement-noise model, calibrated learning rate with a law-misfit floor,
adaptive model-discrepancy noise, guided proposal).
"""

from .filter import Estimate, FilterSettings, ParticleFilter, learning_rates
from .likelihood import LawSettings, Raster, SampleFit, SampleStats, fit_sample, loglik_raster, loglik_sample
from .resampling import effective_sample_size, resample
from .run import Sample, make_estimator, run_filter
from .ukf import UKFEstimator, UKFSettings

__all__ = ["ParticleFilter", "FilterSettings", "Estimate", "learning_rates", "LawSettings", "Raster", "SampleFit",
           "SampleStats", "fit_sample", "loglik_raster", "loglik_sample", "resample", "effective_sample_size",
           "Sample", "run_filter", "make_estimator", "UKFEstimator", "UKFSettings"]
