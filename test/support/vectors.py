"""Small vector maths for the reference solutions of the tests.

``np.cross`` spends tens of microseconds per call on its axis handling, which dominates a
reference integrated over tens of thousands of steps; ``cross`` is the textbook formula for
two 3-vectors (``test/models/test_rigid_body.py`` checks it against ``np.cross``).
"""

from __future__ import annotations

import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of two 3-vectors."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
