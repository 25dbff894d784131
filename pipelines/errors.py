"""Errors the pipelines raise for bad input: the CLI prints them as one line."""


class InputError(Exception):
    """An input file is missing something the pipeline needs; the message names the file and what."""


class OutputError(Exception):
    """An output path cannot be used (it is an input, a directory, or not writable); the message names it."""


class OptionError(ValueError):
    """An option's value is refused; the message names where it was given (flag, file and line) and why."""
