"""Plain numpy/scipy reference implementations, written from the paper's equations.

They are slow on purpose (readable, step by step) and serve as oracles: the tests
cross-check the Rust core against them. See :mod:`avll.reference.rollout`.
"""

from . import rollout

__all__ = ["rollout"]
