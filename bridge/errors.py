"""Errors that a user can act on: printed as one line, exit status 2."""


class UserError(Exception):
    """A problem with the user's input (file, option, device), stated in one line."""
