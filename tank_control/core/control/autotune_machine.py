"""The operator side shared by the auto-tuners: start, abort, apply, revert and commands.

The relay PID tuner (relay_autotune.py), the auto-tuned Smith predictor (smith_autotune.py)
and the two-loop PI tuner (mimo_autotune.py) differ in their tests; what an operator (a
node's std_srvs/Trigger services, the dashboard, a scenario's scheduled start) can ask of
them, and the answers, are written once here. Each answer is ``(accepted, message)``, a
Trigger response; a refused request changes nothing. States: docs/controllers.md.
"""
from __future__ import annotations

from collections.abc import Callable

COMMAND_METHODS = {'start_autotune': 'start', 'abort_autotune': 'abort',
                   'apply_autotune': 'apply', 'revert_gains': 'revert'}
"""Trigger service name → method of :class:`AutotuneMachine`."""


class AutotuneMachine:
    """Template of an auto-tuner's operator requests over its ``_state`` and ``_reason``.

    A tuner provides :attr:`TESTING` (the states of a running test), ``_begin`` (start a
    test that may start), ``_end(state, reason)`` (leave a test, restoring the loop from
    before it) and, if it offers apply/revert (:attr:`COMMANDS`), the ``_proposal``/``_saved``
    hooks below.
    """

    TESTING: tuple[str, ...] = ()
    COMMANDS: tuple[str, ...] = tuple(COMMAND_METHODS)
    RESTORED = 'previous gains restored'
    """What an abort restores, in its message."""

    _state: str
    _reason: str

    @property
    def state(self) -> str:
        return self._state

    # ------------------------------------------------------------------ requests
    def start(self) -> tuple[bool, str]:
        """Begin a test (not while one runs, nor when ``_start_refusal`` says why not)."""
        if self._state in self.TESTING:
            return False, f'autotune: a test is already running (state {self._state})'
        refusal = self._start_refusal()
        if refusal:
            return False, f'autotune: {refusal}'
        return self._begin()

    def abort(self, reason: str = 'abort requested') -> tuple[bool, str]:
        """End a running test now; the loop from before it resumes bumplessly."""
        if self._state not in self.TESTING:
            return False, f'autotune: no test is running (state {self._state})'
        self._end('aborted', reason)
        return True, f'autotune: test aborted, {self.RESTORED}'

    def apply(self) -> tuple[bool, str]:
        """Run the pending proposal bumplessly (state ``running``)."""
        if self._state in self.TESTING:
            return False, f'autotune: a test is running (state {self._state})'
        if not self._has_proposal():
            return False, 'autotune: no proposal to apply; run a test first'
        refusal = self._apply_refusal()
        if refusal:
            return False, f'autotune: proposal not applied: {refusal}'
        message = self._apply_proposal()
        return True, f'autotune: {message}'

    def revert(self) -> tuple[bool, str]:
        """Return to the gains from before the last test, bumplessly (state ``reverted``; a
        running test is aborted, which restores them too)."""
        if not self._has_saved():
            return False, 'autotune: no gains from before a test to return to'
        if self._state in self.TESTING:
            self._end('aborted', 'revert requested')
            return True, 'autotune: test aborted, gains from before the test restored'
        self._restore_saved()
        self._state, self._reason = 'reverted', ''
        return True, 'autotune: gains from before the test restored'

    def command(self, name: str) -> tuple[bool, str]:
        """The operator command ``name`` (one of :attr:`COMMANDS`, a Trigger service)."""
        if name not in self.COMMANDS:
            raise ValueError(f'command: {name!r} is unknown; allowed ' + ', '.join(self.COMMANDS))
        method: Callable[[], tuple[bool, str]] = getattr(self, COMMAND_METHODS[name])
        return method()

    # ------------------------------------------------------------------ hooks
    def _start_refusal(self) -> str:
        """Why a test may not start now ('' if it may)."""
        return ''

    def _begin(self) -> tuple[bool, str]:
        raise NotImplementedError

    def _end(self, state: str, reason: str) -> None:
        raise NotImplementedError

    def _has_proposal(self) -> bool:
        return False

    def _apply_refusal(self) -> str:
        """Why the pending proposal may not run ('' if it may)."""
        return ''

    def _apply_proposal(self) -> str:
        """Run the pending proposal; the message after ``autotune: ``."""
        raise NotImplementedError

    def _has_saved(self) -> bool:
        return False

    def _restore_saved(self) -> None:
        raise NotImplementedError
