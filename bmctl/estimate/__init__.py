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


def __getattr__(name: str):
    """``UKFEstimator`` and ``UKFSettings`` on first use: filterpy imports scipy.stats (~1 s)."""
    if name in ("UKFEstimator", "UKFSettings"):
        from . import ukf

        return getattr(ukf, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ParticleFilter", "FilterSettings", "Estimate", "learning_rates", "LawSettings", "Raster", "SampleFit",
           "SampleStats", "fit_sample", "loglik_raster", "loglik_sample", "resample", "effective_sample_size",
           "Sample", "run_filter", "make_estimator", "UKFEstimator", "UKFSettings"]
