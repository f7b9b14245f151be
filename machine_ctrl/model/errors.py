"""Errors that cross module boundaries."""


class ConfigError(ValueError):
    """A machine description (or other configuration) that cannot be used; the message is one
    line naming the file, the key and the problem."""


class InvalidMessage(ValueError):
    """A message another node sent that we refuse; the text is the reason."""
