"""The package's exceptions and warnings about a finger's description (their own module:
the contact model and the finger both raise them, and the finger holds a contact model)."""


class FingerError(ValueError):
    """An invalid finger description."""


class FingerWarning(UserWarning):
    """A valid finger with a likely mistake (a load the adaptor carries, for example)."""
