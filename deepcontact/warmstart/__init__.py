"""Warm starts: where the projected Gauss-Seidel solver begins, the project's subject.

The public names: `StepContext` (what a start sees), `StartValue` (what it returns),
`STARTS` (the registry built-ins and plug-ins share) and `make_starts` (names to starts)."""
from .starts import STARTS, StartValue, StepContext, make_starts

__all__ = ["STARTS", "StartValue", "StepContext", "make_starts"]
