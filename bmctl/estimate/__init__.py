"""State and parameter estimation from micrograph samples: likelihood, resampling, particle filter."""

from .filter import Estimate, FilterSettings, ParticleFilter
from .likelihood import SampleStats, loglik_sample
from .resampling import effective_sample_size, resample

__all__ = ["ParticleFilter", "FilterSettings", "Estimate", "SampleStats", "loglik_sample", "resample",
           "effective_sample_size"]
