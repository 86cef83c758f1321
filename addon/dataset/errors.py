"""The one error of the dataset writers."""
from __future__ import annotations


class ExportError(ValueError):
    """A camera or scene cannot be exported; the message names the object or file."""
