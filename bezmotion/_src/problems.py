"""Checks of values that only a computation knows, raised two ways from one description.

A :class:`Problem` is a row of flags (``bad``, one per item: a key, a handle slot) and the
message for each item. Inside a caller's ``jax.jit`` the problems become ``eqx.error_if``
checks (:func:`raised_in_program`), which raise when the computation runs. Called with
concrete inputs, an entry point computes them in a small jitted function of its own and
raises on the host (:func:`raise_first`), so its main program holds no host callback: XLA's
persistent compilation cache stores no program that does, and the in-between's is the one
that takes longest to compile.

A problem is a pytree whose messages are static, so a jitted function can return a list.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


@jax.tree_util.register_pytree_node_class
class Problem:
    """``bad`` ``(n,)`` bool, one flag per item; ``messages`` ``n`` strings, the one to raise
    for the first item flagged."""

    def __init__(self, bad: Any, messages: Sequence[str]) -> None:
        self.bad, self.messages = bad, tuple(messages)

    def tree_flatten(self):
        return (self.bad,), self.messages

    @classmethod
    def tree_unflatten(cls, messages, children):
        return cls(children[0], messages)

    def __repr__(self) -> str:
        return f"Problem(bad={self.bad!r}, messages={self.messages[:2]}…)"


def raised_in_program(x: Any, problems: Sequence[Problem]) -> Any:
    """``x`` with an ``eqx.error_if`` per problem: the computation raises the first flagged
    item's message when it runs."""
    for problem in problems:
        bad = jnp.reshape(problem.bad, (-1,))
        if len(problem.messages) == 1:
            x = eqx.error_if(x, bad.any(), problem.messages[0])
        else:
            x = eqx.branched_error_if(x, bad.any(), jnp.argmax(bad), list(problem.messages))
    return x


def raise_first(problems: Sequence[Problem]) -> None:
    """Raise ``ValueError`` with the message of the first flagged item of the first problem
    that has one; nothing when none is flagged. ``problems`` hold concrete arrays."""
    for problem in problems:
        bad = np.asarray(problem.bad).reshape(-1)
        if bad.any():
            raise ValueError(problem.messages[int(np.argmax(bad))])


__all__ = ["Problem", "raise_first", "raised_in_program"]
