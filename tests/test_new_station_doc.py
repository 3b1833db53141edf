"""docs/new-station.md, followed to the letter (issue 11 item 5): so that it cannot rot.

Every ```sh block of the document runs, in order, in one empty temporary directory, with
this venv's hubctl and python first on PATH; the directory a block ends in is where the
next one starts. A block must exit 0, unless its fence says ```sh fails. A ```text block
right after it is an excerpt of what it prints: each of its lines must appear in the
output, a "..." in it standing for anything. The project the document installs is removed
from the venv afterwards.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.scaffold_support import generated_projects_removed

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "new-station.md"
FENCE = re.compile(r"^```(?P<info>[^\n]*)\n(?P<body>.*?)^```\s*$", re.MULTILINE | re.DOTALL)
BLOCK_TIMEOUT_S = 600


@dataclass
class Block:
    line: int  # of its fence in the document
    end: int  # offset of the end of its closing fence
    script: str
    fails: bool
    expected: list[str]  # lines of the output excerpt that follows it


def shell_blocks(text: str) -> list[Block]:
    blocks: list[Block] = []
    for match in FENCE.finditer(text):
        info = match.group("info").split()
        line = text.count("\n", 0, match.start()) + 1
        if info[:1] == ["sh"]:
            blocks.append(Block(line, match.end(), match.group("body"), fails=info[1:] == ["fails"], expected=[]))
        elif info[:1] == ["text"] and blocks and not text[blocks[-1].end:match.start()].strip():
            blocks[-1].expected = [ln.strip() for ln in match.group("body").splitlines() if ln.strip()]
    return blocks


def _pattern(excerpt: str) -> re.Pattern[str]:
    return re.compile(".*".join(re.escape(piece.strip()) for piece in excerpt.split("...")))


def test_the_document_has_blocks_to_follow() -> None:
    blocks = shell_blocks(DOC.read_text())
    assert len(blocks) >= 5 and any(b.fails for b in blocks) and all(b.script.strip() for b in blocks)
    assert "hubctl new-station" in blocks[0].script + blocks[1].script


@pytest.mark.slow
def test_following_docs_new_station_md_from_an_empty_directory(tmp_path: Path) -> None:
    text = DOC.read_text()
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("VIRTUAL_ENV", None)
    cwd = tmp_path / "work"
    cwd.mkdir()
    here = tmp_path / "cwd"
    with generated_projects_removed():
        for block in shell_blocks(text):
            began = time.monotonic()
            script = f"set -e\n{block.script}\npwd > {here}\n"
            result = subprocess.run(["bash", "-c", script], cwd=cwd, env=env, text=True, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, timeout=BLOCK_TIMEOUT_S, check=False)
            where = f"{DOC.name}:{block.line} ({time.monotonic() - began:.1f} s):\n{block.script}\n--- output:\n"
            print(f"{DOC.name}:{block.line}: exit {result.returncode} in {time.monotonic() - began:.1f} s")
            if block.fails:
                assert result.returncode != 0, f"expected to fail, passed: {where}{result.stdout}"
            else:
                assert result.returncode == 0, f"failed: {where}{result.stdout}"
                cwd = Path(here.read_text().strip())
            for excerpt in block.expected:
                assert _pattern(excerpt).search(result.stdout), f"{excerpt!r} not in the output of {where}" \
                                                                f"{result.stdout}"
