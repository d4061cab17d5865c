"""Offline continuous-time identification ([A-SRIVC], [BCD-SRIVC], [UNS-SRIVC]): one entry point, :func:`identify`.

``types`` holds the checked data and the result every estimator returns; ``stable`` the LSSVF, SRIVC, CLSRIVC,
additive SRIVC/CLSRIVC and BCD estimators ([A-SRIVC], [BCD-SRIVC]) with the warm-up and initial-transient tests;
``unstable`` the estimators for unstable plants ([UNS-SRIVC]), reached through :func:`identify`'s ``*-uns`` methods.
"""

from .stable import (
    TRANSIENT_FALSE_ALARM,
    WARMUP_DECAY_TIMES,
    TransientTest,
    identify,
    initial_transient_test,
    integrator_free_response,
    match_order,
    min_cost_assignment,
    model_frf,
    output_error_variance,
    relative_change,
    split_additive,
    to_unfactored,
    unfactored_structure,
    warmup_samples,
)
from .types import METHODS, IdentificationResult, OfflineData

__all__ = ["METHODS", "TRANSIENT_FALSE_ALARM", "WARMUP_DECAY_TIMES", "IdentificationResult", "OfflineData",
           "TransientTest", "identify", "initial_transient_test",
           "integrator_free_response", "match_order", "min_cost_assignment", "model_frf", "output_error_variance",
           "relative_change", "split_additive", "to_unfactored", "unfactored_structure", "warmup_samples"]
