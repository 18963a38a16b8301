"""Copies and pickles of an object whose compiled step is bound to its arrays.

Why: a compiled step (kalman_step.Step, noise_step.Store) holds buffers of the arrays it was
bound to, so a copy must not share it (it would write into the original's arrays) and a
pickle cannot hold it. The Kalman filter and its noise estimator both are such objects: the
copy drops the step and binds its own to its own arrays.
"""

from __future__ import annotations


class BindsCompiled:
    """`_fast` is the compiled step (None: Python's way), and so is every attribute named in
    COMPILED; `_bind()` binds them to the object's arrays. Copies and pickles leave them out
    and bind their own."""

    _fast = None
    COMPILED: tuple[str, ...] = ("_fast",)

    def _bind(self) -> None:
        raise NotImplementedError

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for name in self.COMPILED:
            state[name] = None
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._bind()
