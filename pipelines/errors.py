"""Errors the pipelines raise for bad input: the CLI prints them as one line."""


class InputError(Exception):
    """An input file is missing something the pipeline needs; the message names the file and what."""
