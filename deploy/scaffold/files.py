"""Writing a station project: templates, new files, and small edits of the files a person also edits.

Templates are `string.Template` files (`$name`) in this package's templates/ directory.
Edits of pyproject.toml, hubs.toml and the model module are line insertions at a known
place (a table header, a marker comment), each checked afterwards: a TOML file must still
parse. Every change is recorded, so that the command can say what it did.
"""

from __future__ import annotations

import importlib.resources
import keyword
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from string import Template

from common.config.keylines import KeyLines

IDENTIFIER = re.compile(r"^[a-z][a-z0-9_]*$")


class ScaffoldError(Exception):
    """The project cannot be generated or changed as asked; the message says why and what to do."""


def check_name(kind: str, name: str) -> None:
    """A station or device type name: also a Python module name and an entry-point name."""
    if not IDENTIFIER.match(name) or keyword.iskeyword(name):
        raise ScaffoldError(f"{kind} name {name!r} must be a lowercase Python identifier (letters, digits, _; "
                            f"e.g. 'pick_cell'): it names a Python module")


def render(template: str, **values: str) -> str:
    text = (importlib.resources.files(__package__) / "templates" / f"{template}.tmpl").read_text(encoding="utf-8")
    return Template(text).substitute(values)


@dataclass
class Changes:
    """What a command wrote, relative to the project directory."""

    root: Path
    lines: list[str] = field(default_factory=list)

    def rel(self, path: Path) -> str:
        try:
            return str(path.relative_to(self.root))
        except ValueError:
            return str(path)

    @staticmethod
    def check_new(path: Path, *, force: bool) -> None:
        if path.exists() and not force:
            raise ScaffoldError(f"{path} exists already: not overwritten (--force overwrites the generated files)")

    def create(self, path: Path, text: str, *, force: bool = False) -> None:
        existed = path.exists()
        self.check_new(path, force=force)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        self.lines.append(f"  {'rewrote' if existed else 'wrote'} {self.rel(path)}")

    def edit(self, path: Path, text: str, what: str) -> None:
        if path.suffix == ".toml":
            try:
                tomllib.loads(text)
            except tomllib.TOMLDecodeError as exc:  # our edit broke it: never write that
                raise ScaffoldError(f"{path}: adding {what} would make it invalid TOML ({exc}); add it by "
                                    f"hand") from exc
        path.write_text(text, encoding="utf-8")
        self.lines.append(f"  changed {self.rel(path)}: {what}")


def insert_at_marker(text: str, marker: str, line: str, path: Path) -> str:
    """`line` inserted at the line holding `marker`, with its indentation: above it, or, for a marker
    that says "below this line", into the sorted run of lines under it (imports stay sorted)."""
    lines = text.splitlines(keepends=True)
    for i, existing in enumerate(lines):
        if marker not in existing:
            continue
        indent = existing[: len(existing) - len(existing.lstrip())]
        at = i
        if "below this line" in marker:
            at = i + 1
            while at < len(lines) and lines[at].lstrip().startswith(("from ", "import ")) and lines[at].strip() < line:
                at += 1
        lines.insert(at, f"{indent}{line}\n")
        return "".join(lines)
    raise ScaffoldError(f"{path} has no line '# {marker}': add the resource to the model yourself (a function "
                        f"returning a Resource of that device type, called in build_model), then run this again")


def toml_key(path: tuple[str, ...]) -> str:
    return ".".join(part if re.fullmatch(r"[A-Za-z0-9_-]+", part) else f'"{part}"' for part in path)


def add_to_table(text: str, table: tuple[str, ...], new_lines: list[str], path: Path) -> str:
    """`new_lines` appended to the TOML table `table` (after its last key), or the table appended with them."""
    node: object = tomllib.loads(text)
    for part in table:
        node = node.get(part) if isinstance(node, dict) else None
    lines = text.splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines[-1] += "\n"
    if node is None:
        return "".join(lines) + f"\n[{toml_key(table)}]\n" + "".join(f"{line}\n" for line in new_lines)
    number = KeyLines(text).line_of(table)
    if not isinstance(node, dict) or number is None or not lines[number - 1].lstrip().startswith("["):
        raise ScaffoldError(f"{path}: [{toml_key(table)}] is not written as a table of its own: add "
                            f"{'; '.join(new_lines)} to it by hand")
    end = number
    while end < len(lines) and not lines[end].lstrip().startswith("["):
        end += 1
    last_key = max((i for i in range(number - 1, end) if lines[i].strip() and not lines[i].lstrip().startswith("#")),
                   default=number - 1)
    lines[last_key + 1:last_key + 1] = [f"{line}\n" for line in new_lines]
    return "".join(lines)
