"""Errors raised on bad input.

Every check in :mod:`sdm` raises :class:`SDMInputError` (a ``ValueError``) with a
message that names the offending argument, file or config key and says what is
wrong, so that no bad input surfaces as a bare traceback from deep inside torch.
"""


class SDMInputError(ValueError):
    """Bad input to an :mod:`sdm` function: the message says which and why."""
