"""Errors of the schemas package: one base class; the recorder and replay translate it."""


class ContractError(ValueError):
    """A value breaks the recording contract (metadata record, vocabulary, layout).

    The message names the value and the rule; callers that know the file prepend its path.
    """


class CdrError(ContractError):
    """Message bytes break the CDR rules (a length or count beyond the message, nesting).

    The message names the field and the byte; the reader and the import translate it into
    their own errors, naming the file and the fix.
    """
