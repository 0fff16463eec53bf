"""The worked vial-reading example of docs/campaign.md ("Vial readings") is what the commands print:
its ``$ bmctl ...`` lines are run as shown, and every other line of the block must be printed by the
command above it (a part of what it prints, in its order)."""

from __future__ import annotations

import shlex
from pathlib import Path

from bmctl.cli import main

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "campaign.md"
#: the sentence that leads into the example's code block
LEAD = "on a campaign with a 60 °C ceiling"


def _example() -> list[tuple[list[str], list[str]]]:
    """(command arguments, the lines the doc shows it printing) of the example's block."""
    text = DOC.read_text(encoding="utf-8")
    block = text[text.index(LEAD):].split("```\n", 2)[1]
    steps: list[tuple[list[str], list[str]]] = []
    for line in block.splitlines():
        if line.startswith("$ "):
            words = shlex.split(line[2:])
            assert words[0] == "bmctl", line
            steps.append((words[1:], []))
        elif line.strip():
            assert steps, f"{DOC}: the example shows output before any command: {line}"
            steps[-1][1].append(line)
    return steps


def test_vial_reading_example_matches_what_the_commands_print(tmp_path, capsys, monkeypatch):
    steps = _example()
    assert len(steps) == 3 and sum(len(shown) for _, shown in steps) >= 5
    monkeypatch.chdir(tmp_path)  # the campaign folder is made here; the repository's files by their full path
    for args, shown in steps:
        args = [str(ROOT / a) if "/" in a and (ROOT / a).exists() else a for a in args]
        assert main(args) == 0, args
        cap = capsys.readouterr()
        printed = (cap.out + cap.err).splitlines()
        at = 0
        for line in shown:  # each shown line is printed, in the order shown
            assert line in printed[at:], f"docs/campaign.md shows {line!r}; `bmctl {' '.join(args)}` printed:\n" \
                                         + "\n".join(printed)
            at = printed.index(line, at) + 1
