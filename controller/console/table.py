"""A DataTable that is given whole panels (`key -> row`) and changes only what differs.

DataTable renders only the lines in view, so a table of thousands of rows costs what is
visible; what a redraw must not do is rebuild it. `sync()` updates the changed cells
when the rows are the same, appends or removes rows when that is all that happened, and
rebuilds only when the rows were reordered (a new filter), keeping the cursor on its row.
Columns grow to fit and never shrink: DataTable re-measures a whole column when a cell
gets narrower, which for thousands of rows costs more than the redraw itself.
"""

from __future__ import annotations

from collections.abc import Sequence

from rich.cells import cell_len
from rich.text import Text
from textual.widgets import DataTable

from .view import Cell, Row

REMOVALS_BEFORE_REBUILD = 32  # removing a row is linear in the table: beyond this, rebuild once


class RowTable(DataTable[Cell]):
    def __init__(self, columns: Sequence[str], *, title: str, id: str) -> None:
        super().__init__(id=id, cursor_type="row")
        self.border_title = title
        self._labels = tuple(columns)
        self._keys = tuple(f"c{i}" for i in range(len(columns)))
        self._rows: dict[str, Row] = {}
        self._widths = [cell_len(label) for label in self._labels]

    def on_mount(self) -> None:
        for label, key in zip(self._labels, self._keys, strict=True):
            self.add_column(label, key=key)

    @property
    def shown(self) -> dict[str, Row]:
        return self._rows

    def selected_key(self) -> str | None:
        if self.row_count == 0:
            return None
        row_key, _ = self.coordinate_to_cell_key(self.cursor_coordinate)
        return row_key.value

    def select(self, key: str) -> None:
        self.move_cursor(row=self.get_row_index(key))

    def sync(self, rows: dict[str, Row]) -> int:
        """Show `rows`; returns how many cells (or rows) changed."""
        old = self._rows
        old_keys, new_keys = list(old), list(rows)
        if new_keys == old_keys:
            return self._update_cells(rows)
        kept = [k for k in old_keys if k in rows]
        if new_keys[: len(old_keys)] == old_keys:
            changed = self._update_cells({k: rows[k] for k in old_keys})
            for key in new_keys[len(old_keys):]:
                self._add(key, rows[key])
            self._rows = dict(rows)
            return changed + len(new_keys) - len(old_keys)
        if kept == new_keys and len(old_keys) - len(kept) <= REMOVALS_BEFORE_REBUILD:
            for key in old_keys:
                if key not in rows:
                    self.remove_row(key)
            self._rows = {k: old[k] for k in kept}
            return self._update_cells(rows) + len(old_keys) - len(kept)
        return self._rebuild(rows)

    def _update_cells(self, rows: dict[str, Row]) -> int:
        changed = 0
        old = self._rows
        for key, row in rows.items():
            before = old[key]
            if row == before:
                continue
            for column, (cell, was) in enumerate(zip(row, before, strict=True)):
                if cell != was:
                    self.update_cell(key, self._keys[column], cell, update_width=self._grows(column, cell))
                    changed += 1
        self._rows = dict(rows)
        return changed

    def _rebuild(self, rows: dict[str, Row]) -> int:
        selected = self.selected_key()
        self.clear()
        for key, row in rows.items():
            self._add(key, row)
        self._rows = dict(rows)
        if selected in rows:
            self.select(selected)
        return len(rows)

    def _add(self, key: str, row: Row) -> None:
        for column, cell in enumerate(row):
            self._grows(column, cell)
        self.add_row(*row, key=key)

    def _grows(self, column: int, cell: Cell) -> bool:
        """Whether `cell` is wider than its column so far (DataTable then widens it, cheaply)."""
        width = cell_len(cell.plain if isinstance(cell, Text) else cell)
        if width <= self._widths[column]:
            return False
        self._widths[column] = width
        return True
