"""Test configuration.

The jaxtyping import hook is installed *before anything imports bezmotion*, so every
annotated function and dataclass in the package is checked at runtime with beartype
during the whole test session (shape and dtype annotations included).
"""

from jaxtyping import install_import_hook

install_import_hook("bezmotion", "beartype.beartype")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from helpers import SHARED_DATA, requires_shared  # noqa: E402,F401  (re-exported for test modules)


@pytest.fixture
def rng() -> np.random.Generator:
    """A fresh, fixed-seed NumPy generator per test (tests are independent of their order)."""
    return np.random.default_rng(20240531)


@pytest.fixture
def x64():
    """Run the test body with 64-bit JAX arrays enabled (for finite-difference checks)."""
    with jax.enable_x64(True):
        yield
