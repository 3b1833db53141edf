"""A station in PDDL: the compiled model from a start state to goals as a planning task (`encode`), written
as a domain and a problem (`render`) or in Fast Downward's SAS+ (`render_sas`), and Fast Downward and SymK on
it (`downward`, test-time oracles). docs/pddl.md describes the encoding and what it leaves out."""

from .encoding import Action, Task, encode
from .formulas import Unexpressible
from .sas import render_sas
from .writer import Flavour, render

__all__ = ["Action", "Flavour", "Task", "Unexpressible", "encode", "render", "render_sas"]
