"""Modelling and numerical choices are objects (a base kind, a torsion constant, a linear
solver, an integration scheme); finger and solver files name them by words. `choice`
turns a field's value into its object, accepting the word for one release with a
DeprecationWarning, and names the field and value when it is neither."""

import warnings

from ._errors import FingerError


def choice(value, field: str, kind: type, named: dict, error=FingerError):
    """`value` if it is a `kind`; the object `named[value]` (deprecated) for its word."""
    if isinstance(value, kind):
        return value
    if isinstance(value, str) and value in named:
        obj = named[value]
        warnings.warn(
            f"{field} = {value!r} is deprecated: pass finray_jax.{type(obj).__name__}()",
            DeprecationWarning,
            stacklevel=5,
        )
        return obj
    options = ", ".join(f"{type(o).__name__}()" for o in named.values())
    raise error(f"{field} must be one of {options}, got {value!r}")
