"""Errors of the schemas package: one base class; the recorder and replay translate it."""


class ContractError(ValueError):
    """A value breaks the recording contract (metadata record, vocabulary, layout).

    The message names the value and the rule; callers that know the file prepend its path.
    """
