"""ATIKT: active tactile instance knowledge transfer with Gaussian-process classifiers.

Pure numpy/scipy: takes arrays, never files (Feng, Kaboli & Cheng, TUM 2017).
"""

from atikt.errors import AtiktError, NotFittedError, NumericalError

__all__ = ["AtiktError", "NotFittedError", "NumericalError"]
