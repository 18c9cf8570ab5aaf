"""The thesis's studies over a dataset: designs, shared task running, reports as data.

One module per study design (``_fusion``, ``_transfer`` with single-action, ``_priors``,
``_negative``, ``_borrow`` with cross-action and cross-rig), each a :class:`Study` registered in
:data:`STUDIES` (``_registry``); tasks run through ``_running``; a study's summary is declared
as a :class:`Report` (``_report``) and written, with its figure, by ``replay.outputs``.
"""

from replay.studies._registry import STUDIES, find_study
from replay.studies._report import Curves, Report, Section
from replay.studies._running import Study, StudyConfig, dataset_actions, study_results

__all__ = [
    "STUDIES",
    "Curves",
    "Report",
    "Section",
    "Study",
    "StudyConfig",
    "dataset_actions",
    "find_study",
    "study_results",
]
