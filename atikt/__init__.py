"""ATIKT: active tactile instance knowledge transfer with Gaussian-process classifiers.

Pure numpy/scipy: takes arrays, never files (Feng, Kaboli & Cheng, TUM 2017).
"""

from atikt.active import ActiveLearner, StepRecord, entropy
from atikt.errors import AtiktError, NotFittedError, NumericalError
from atikt.features import (
    FEATURE_BLOCKS,
    FeatureTransformer,
    RawFeatures,
    extract_features,
    hjorth,
    linear_correlation,
    stiffness,
    texture,
    thermal_sequence,
)
from atikt.gpc import (
    BinaryGPC,
    LaplaceMode,
    MultiModalGPC,
    OneVsAllGPC,
    laplace_evidences,
    laplace_mode,
)
from atikt.kernels import (
    DependentKernel,
    Kernel,
    ModalityKernel,
    MultiSourceKernel,
    SliceRBF,
    modality_kernel,
)
from atikt.options import LearnerOptions
from atikt.priors import PriorModel, fit_prior_model, fit_prior_models
from atikt.strategies import (
    Density,
    Evidence,
    NoTransfer,
    ObjectFit,
    Optimization,
    Prediction,
    TransferStrategy,
    register_strategy,
    strategy_names,
    transfer_strategy,
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
    "FEATURE_BLOCKS",
    "ActiveLearner",
    "AtiktError",
    "BinaryGPC",
    "Density",
    "DependentKernel",
    "Evidence",
    "FeatureTransformer",
    "Kernel",
    "LaplaceMode",
    "LearnerOptions",
    "ModalityKernel",
    "MultiModalGPC",
    "MultiSourceKernel",
    "NoTransfer",
    "NotFittedError",
    "NumericalError",
    "ObjectDensities",
    "ObjectFit",
    "OneVsAllGPC",
    "Optimization",
    "Prediction",
    "PriorChoice",
    "PriorModel",
    "RawFeatures",
    "SliceRBF",
    "StepRecord",
    "TransferGPC",
    "TransferStrategy",
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
    "laplace_evidences",
    "laplace_mode",
    "linear_correlation",
    "modality_kernel",
    "register_strategy",
    "relatedness",
    "shared_observations",
    "stiffness",
    "strategy_names",
    "texture",
    "thermal_sequence",
    "transfer_strategy",
]
