"""Errors of the evaluation layer: bad input the CLI turns into one line and exit code 2."""

from __future__ import annotations


class EvaluationError(ValueError):
    """Bad evaluation input (agent, suite, options); the message says what is valid."""


class AgentSpecError(EvaluationError):
    """An agent spec that names no built-in agent, trained model or importable class."""


class SuiteError(EvaluationError):
    """A suite that does not exist or whose file is invalid."""
