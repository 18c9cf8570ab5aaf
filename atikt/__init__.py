"""ATIKT: active tactile instance knowledge transfer with Gaussian-process classifiers.

Pure numpy/scipy: takes arrays, never files (Feng, Kaboli & Cheng, TUM 2017).
"""

from atikt.active import (
    ActiveLearner,
    PriorModel,
    StepRecord,
    entropy,
    fit_prior_model,
    fit_prior_models,
)
from atikt.errors import AtiktError, NotFittedError, NumericalError
from atikt.features import (
    MODALITIES,
    FeatureTransformer,
    RawFeatures,
    extract_features,
    hjorth,
    linear_correlation,
    stiffness,
    texture,
    thermal_sequence,
)
from atikt.gpc import BinaryGPC, LaplaceMode, MultiModalGPC, OneVsAllGPC, laplace_mode
from atikt.kernels import (
    DependentKernel,
    Kernel,
    ModalityKernel,
    MultiSourceKernel,
    SliceRBF,
    modality_kernel,
)
from atikt.transfer import (
    ObjectDensities,
    PriorChoice,
    TransferGPC,
    choose_by_density,
    choose_by_evidence,
    choose_by_optimization,
    choose_by_prediction,
    evidence_gains,
    relatedness,
    shared_observations,
)

__all__ = [
    "MODALITIES",
    "ActiveLearner",
    "AtiktError",
    "BinaryGPC",
    "DependentKernel",
    "FeatureTransformer",
    "Kernel",
    "LaplaceMode",
    "ModalityKernel",
    "MultiModalGPC",
    "MultiSourceKernel",
    "NotFittedError",
    "NumericalError",
    "ObjectDensities",
    "OneVsAllGPC",
    "PriorChoice",
    "PriorModel",
    "RawFeatures",
    "SliceRBF",
    "StepRecord",
    "TransferGPC",
    "choose_by_density",
    "choose_by_evidence",
    "choose_by_optimization",
    "choose_by_prediction",
    "entropy",
    "evidence_gains",
    "extract_features",
    "fit_prior_model",
    "fit_prior_models",
    "hjorth",
    "laplace_mode",
    "linear_correlation",
    "modality_kernel",
    "relatedness",
    "shared_observations",
    "stiffness",
    "texture",
    "thermal_sequence",
]
