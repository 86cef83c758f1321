"""The errors of bad input that the contract raises (standard library only): each message names the file,
frame and field concerned.
"""
from __future__ import annotations


class DatasetError(Exception):
    """Bad dataset input; the message names the file, frame and field concerned."""


class PoseError(ValueError):
    """A camera matrix that is not a finite rigid transform."""
