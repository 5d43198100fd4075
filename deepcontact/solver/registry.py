"""The registry of solver methods (`--accelerate`), apart from the methods themselves: what a
solve's settings ask whether a name can name a method without importing the solver."""
from ..plugins import Registry

SOLVERS = Registry("solver method", "deepcontact.solvers")
