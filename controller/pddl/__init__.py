"""A station in PDDL: the compiled model from a start state to goals as a planning task (`encode`), written
as a domain and a problem (`render`), and Fast Downward on it (`downward`, a test-time oracle). docs/pddl.md
describes the encoding and what it leaves out."""

from .encoding import Action, Task, encode
from .formulas import Unexpressible
from .writer import Flavour, render

__all__ = ["Action", "Flavour", "Task", "Unexpressible", "encode", "render"]
