"""Test configuration: float64 and strict dtype promotion (as in diffrax's test/conftest.py).

Both are set before any test module imports finray_jax, so every test runs in float64 and
any silent int/float or float32/float64 promotion inside the package raises.
"""

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
