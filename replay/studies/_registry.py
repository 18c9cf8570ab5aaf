"""Every study by name: what ``atikt-replay study NAME`` and ``study all`` run.

A study is one module defining its design (tasks, the task function, its report) as a
:class:`~replay.studies._running.Study`; adding one is that module plus its line here.
``study all`` runs them in this order.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import TYPE_CHECKING

from replay.errors import ReplayError
from replay.studies._borrow import CROSS_ACTION_STUDY, CROSS_RIG_STUDY
from replay.studies._fusion import FUSION
from replay.studies._negative import NEGATIVE
from replay.studies._priors import PRIORS
from replay.studies._transfer import SINGLE_ACTION, TRANSFER
from replay.studies._transfer_check import TRANSFER_CHECK

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replay.studies._running import Study

#: The studies by name, in the order ``study all`` runs them.
STUDIES: Mapping[str, Study] = MappingProxyType(
    {
        study.name: study
        for study in (
            FUSION,
            TRANSFER,
            SINGLE_ACTION,
            PRIORS,
            NEGATIVE,
            CROSS_ACTION_STUDY,
            CROSS_RIG_STUDY,
            TRANSFER_CHECK,
        )
    }
)


def find_study(name: str) -> Study:
    """Return the study of this name.

    Raises:
        ReplayError: No study has this name (the message lists them).
    """
    if name not in STUDIES:
        msg = f"unknown study {name!r}; choose one of {', '.join([*STUDIES, 'all'])}"
        raise ReplayError(msg)
    return STUDIES[name]
