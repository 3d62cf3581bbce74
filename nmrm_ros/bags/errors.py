"""`BagError`: the one error of reading, writing and repairing bags."""


class BagError(ValueError):
    """A bag cannot be read as asked (missing, malformed, truncated, inconsistent)."""
