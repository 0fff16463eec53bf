"""The command lines docs/*.md show still parse with the current code, and the repository files they
name exist (quick: nothing is run).

What is read as a command: a line of a fenced code block (``python``, ``toml`` and ``json`` blocks
aside) or of an indented code block, and an inline code span (a line break inside it read as a
space), that starts with ``bmctl`` or ``python`` (after ``$ ``, ``VAR=value`` prefixes and ``nice``).
A code line ending in ``\\`` goes on on the next. ``A; B`` and ``A && B`` are two commands; a
pipeline's first command is read, redirections are dropped, ``#`` starts a comment.

How each is checked:

* ``bmctl ...`` and ``python -m bmctl ...``: parsed by :func:`bmctl.cli.build_parser`;
* ``python SCRIPT ARGS``: the script exists in the repository and ARGS parse with its own argument
  parser, taken at its ``parse_args`` call (tests/test_results_commands.py; none of its work runs);
  a ``--cases`` of ``benchmarks/hidden_mills.py`` names mills it knows;
* ``python -m pytest PATH...``: the paths exist; ``python -m MODULE``: the module exists;
  ``python -c CODE``: the code compiles. Any other program is a failure, never a skip.

Placeholders are the user's values: an ALL-CAPS word (``DIR``, ``N``, ``FILE``, ``OUT.toml``,
``CARD.toml``) or a ``<word>`` in a token (``models/<card>.toml``) passes any type and any choice;
user file names (``my-mill.toml``, ``run300.toml``) are values like any other. Only a path whose
first folder is one of :data:`REPO_FOLDERS` must exist (not one given to an option that names an
output, such as ``--out``).

A command is parsed in full (its required arguments included; an option spelled out, never
abbreviated). A *sketch* is read leniently (every word shown must be accepted; required arguments,
and an option's value, may be left out): an inline ``bmctl`` span that gives no value past its
subcommand (prose naming a subcommand and options: ``bmctl trial --campaign``, ``bmctl card show``),
and any command with ``[optional]`` parts, ``a|b`` alternatives (every alternative is checked),
``...`` or a ``<word>``, or ``--help``.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import functools
import importlib.util
import io
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest

from bmctl.cli import COMMANDS, build_parser
from bmctl.errors import InputError

from .conftest import ROOT
from .test_readme import SHIPPED
from .test_results_commands import AFTER_PARSE, OUTPUT_OPTIONS, parse_with_script, script_parser

DOCS = sorted((ROOT / "docs").glob("*.md"))
#: a path whose first part is one of these must exist in the repository
REPO_FOLDERS = (*SHIPPED, "benchmarks", "tests")
#: options whose value is something the command writes, never a file it must find
WRITES = OUTPUT_OPTIONS | {"--write-card", "--figures"}
#: fenced blocks of these languages hold no command lines
NOT_SHELL = {"python", "toml", "json", "csv"}

_FENCE = re.compile(r"^\s*(```|~~~)\s*([\w+-]*)")
_COMMAND = re.compile(r"^(\$ )?([A-Za-z_]\w*=\S+ |nice (-n \d+ |-\d+ )?)*(bmctl|python3?)( |$)")
_SPAN = re.compile(r"(?<!`)`([^`\n]+(?:\n[^`\n]+)*)`(?!`)")
_PLACEHOLDER = re.compile(r"^[A-Z][A-Z0-9_]*(\.[A-Za-z0-9]+)?$|<\w[\w-]*>")
_REDIRECT_ALONE = re.compile(r"^\d*(>>?|<)(&\d+)?$")
_REDIRECT_JOINED = re.compile(r"^\d*>>?(&\d+|\S+)$")


@dataclass(frozen=True)
class Shown:
    """A command line as a doc shows it."""

    where: str  # docs/NAME.md:LINE
    text: str
    inline: bool


def shown_commands(path: Path, text: str | None = None) -> list[Shown]:
    """The command lines ``path`` shows (``text``: its content, read from the file when None)."""
    lines = (path.read_text(encoding="utf-8") if text is None else text).splitlines()
    name = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else path.name
    out: list[Shown] = []
    para: list[tuple[int, str]] = []

    def spans():
        text = "\n".join(t for _, t in para)
        starts = [0]
        for _, t in para:
            starts.append(starts[-1] + len(t) + 1)
        for m in _SPAN.finditer(text):
            span = " ".join(m.group(1).split())
            if _COMMAND.match(span):
                line = para[max(k for k, s in enumerate(starts[:-1]) if s <= m.start())][0]
                out.append(Shown(f"{name}:{line}", span, inline=True))
        para.clear()

    fence, code, code_at = None, "", 0
    for n, line in enumerate(lines, 1):
        m = _FENCE.match(line)
        if m and (fence is None or not m.group(2)):
            spans()
            if code:  # the block's last line ended in a backslash
                out.append(Shown(f"{name}:{code_at}", code, inline=False))
                code, code_at = "", 0
            fence = (m.group(2).lower() or "-") if fence is None else None
            continue
        indented = fence is None and line.startswith("    ") and (code or _COMMAND.match(line.strip()))
        if (fence is not None and fence not in NOT_SHELL) or indented:
            spans()
            text = line.strip()
            if code or _COMMAND.match(text):
                code, code_at = (f"{code} {text}" if code else text), (code_at or n)
                if code.endswith("\\"):
                    code = code[:-1].rstrip()
                else:
                    out.append(Shown(f"{name}:{code_at}", code, inline=False))
                    code, code_at = "", 0
            continue
        if fence is not None:
            continue
        if line.strip():
            para.append((n, line))
        else:
            spans()
    spans()
    return out


SHOWN = [s for doc in DOCS for s in shown_commands(doc)]


def is_placeholder(word: str) -> bool:
    return bool(_PLACEHOLDER.search(word))


def _steps(text: str) -> list[list[str]]:
    """The commands of a shown line: split at ``;``, ``&&`` and ``||``, a pipeline cut to its first
    command, redirections dropped (a ``|`` inside ``[...]`` separates alternatives)."""
    steps, cur, depth, piped = [], [], 0, False
    words = shlex.split(text.removeprefix("$ "), comments=True)
    k = 0
    while k < len(words):
        w = words[k]
        k += 1
        end = w.endswith(";") and w != ";"
        w = w.removesuffix(";") if end else w
        if w in (";", "&&", "||"):
            steps.append(cur)
            cur, piped = [], False
            continue
        if piped:
            pass
        elif w == "|" and depth == 0:
            piped = True
        elif depth == 0 and _REDIRECT_ALONE.match(w):
            k += 1  # and its file
        elif depth == 0 and _REDIRECT_JOINED.match(w):
            pass
        else:
            depth += w.count("[") - w.count("]")
            cur.append(w)
        if end:
            steps.append(cur)
            cur, piped = [], False
    steps.append(cur)
    return [s for s in steps if s]


def _variants(words: list[str]) -> tuple[list[list[str]], bool]:
    """The argument lists a sketch stands for, and whether it is a sketch. ``[x]`` is shown (x
    included), ``[a | b]`` and ``a|b`` give one variant per alternative, ``...`` is dropped."""
    sketch = False
    points: list[list[list[str]]] = []  # each: alternatives, each a list of words
    k = 0
    while k < len(words):
        w = words[k]
        if w.startswith("["):  # an optional group, to its closing "]"
            group, depth = [], 0
            while k < len(words):
                depth += words[k].count("[") - words[k].count("]")
                group.append(words[k])
                k += 1
                if depth <= 0:
                    break
            alts, cur = [], []
            for g in (g.replace("[", "").replace("]", "") for g in group):  # [a [b]]: a and b shown
                if g == "|":
                    alts.append(cur)
                    cur = []
                elif g:
                    cur.append(g)
            alts.append(cur)
            sketch, expanded = True, []
            for alt in alts:  # a word with its own alternatives inside the group (--objective a|b|c)
                j = next((i for i, x in enumerate(alt) if "|" in x), None)
                expanded += [alt] if j is None else [alt[:j] + [x] + alt[j + 1:] for x in alt[j].split("|")]
            points.append([[x for x in alt if x not in ("...", "…")] for alt in expanded])
            continue
        k += 1
        if w in ("...", "…"):
            sketch = True
            continue
        if w.endswith(("...", "…")):  # IMAGE...: repeated
            sketch, w = True, w.rstrip(".…")
        m = re.fullmatch(r"([^\[]*)\[([^\]]*)\](.*)", w)
        if m:  # name[_a|_b]: the name alone and with each ending
            sketch = True
            points.append([[m.group(1) + m.group(3)]] + [[m.group(1) + x + m.group(3)] for x in m.group(2).split("|")])
        elif "|" in w:
            sketch = True
            points.append([[x] for x in w.split("|")])
        else:
            if "<" in w:
                sketch = True
            points.append([[w]])
    n = max((len(p) for p in points), default=1)
    return [[x for p in points for x in p[min(i, len(p) - 1)]] for i in range(n)], sketch


class _Choices(list):
    """Choices that also take a placeholder."""

    def __contains__(self, value):
        return (isinstance(value, str) and is_placeholder(value)) or list.__contains__(self, value)


def _accepting(parser: argparse.ArgumentParser, lenient: bool) -> argparse.ArgumentParser:
    """``parser`` (changed in place) with placeholders passing every type and choice, options
    spelled out in full (no ``--results-nam`` for ``--results-name``), and with no argument
    required when ``lenient``."""
    stack, seen = [parser], set()
    while stack:
        p = stack.pop()
        if id(p) in seen:
            continue
        seen.add(id(p))
        p.allow_abbrev = False
        if lenient:
            for group in p._mutually_exclusive_groups:
                group.required = False
        for a in p._actions:
            if lenient:
                a.required = False
            if isinstance(a, argparse._SubParsersAction):
                stack.extend(a.choices.values())
                continue
            if a.type is not None:
                convert = p._registry_get("type", a.type, a.type)

                @functools.wraps(convert)
                def passing(text, convert=convert):
                    return text if is_placeholder(text) else convert(text)

                a.type = passing
            if a.choices is not None:
                a.choices = _Choices(a.choices)
    return parser


def parse_problems(parser: argparse.ArgumentParser, argv: list[str], lenient: bool):
    """``(namespace, [])`` when ``parser`` takes ``argv``, else ``(None, [why])``."""
    if any(a in ("-h", "--help") for a in argv):  # help needs nothing else
        argv, lenient = [a for a in argv if a not in ("-h", "--help")], True
    parser = _accepting(parser, lenient)
    for _ in range(len(argv) + 1):
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                return parser.parse_args(argv), []
        except InputError as exc:
            why = f"refused: {exc}"
        except SystemExit as exc:
            why = f"refused (exit {exc.code}): {err.getvalue().strip()[-400:]}"
        # prose may name an option without its value (`bmctl simulate --schedule`): a sketch gets one
        m = re.search(r"argument (-[-\w]+)(?:/\S+)?: expected (?:one|at least one) argument", why)
        if not (lenient and m and m.group(1) in argv):
            return None, [why]
        k = argv.index(m.group(1))
        argv = [*argv[:k + 1], "VALUE", *argv[k + 1:]]
    return None, [why]


def _path_problems(argv: list[str]) -> list[str]:
    out = []
    for k, a in enumerate(argv):
        opt, _, value = a.partition("=") if a.startswith("--") else ("", "", a)
        if (k and argv[k - 1] in WRITES) or opt in WRITES or not value or value.startswith("-") \
                or is_placeholder(value):
            continue
        for part in value.split(","):
            if part.split("/")[0] in REPO_FOLDERS and not (ROOT / part).exists():
                out.append(f"names {part}, which is not in the repository")
    return out


@functools.lru_cache(maxsize=None)
def _script(path: Path):
    return script_parser(path)


def _gives_values(parser: argparse.ArgumentParser, argv: list[str]) -> bool:
    """Whether ``argv`` gives a value past its (sub)command words (a mention names options only)."""
    words = list(argv)
    while words:
        sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        if sub is None or words[0] not in sub.choices:
            break
        parser = sub.choices[words.pop(0)]
    return any(not w.startswith("-") for w in words)


def _bmctl_problems(argv: list[str], lenient: bool, inline: bool = False) -> list[str]:
    """``inline``: a span of prose, read leniently when it only names a subcommand and options."""
    if argv and is_placeholder(argv[0]):  # bmctl <command> --help: any subcommand
        return [p for name in COMMANDS for p in _bmctl_problems([name, *argv[1:]], lenient, inline)]
    parser = build_parser()
    return parse_problems(parser, argv, lenient or (inline and not _gives_values(parser, argv)))[1]


def _script_problems(argv: list[str], lenient: bool) -> list[str]:
    script = (ROOT / argv[0]).resolve()
    if not script.is_file() or ROOT not in script.parents:
        return [f"{argv[0]}: no such script in the repository"]
    parser, found = _script(script)  # found: the script's globals, or why it has no parser
    if parser is None:
        return [f"{argv[0]}: {p}" for p in found]
    ns, problems = parse_problems(copy.deepcopy(parser), argv[1:], lenient)
    after = AFTER_PARSE.get(script.name)
    if ns is not None and after and not lenient and not any(map(is_placeholder, argv)):
        problems += parse_with_script(script, argv[1:], ROOT, after)  # the check past the parser, run as __main__
    return [f"{argv[0]}: {p}" for p in problems]


def _python_problems(argv: list[str], lenient: bool, mention: bool) -> list[str]:
    k = 0
    while k < len(argv) and argv[k].startswith("-") and argv[k] not in ("-m", "-c"):
        k += 2 if argv[k] in ("-X", "-W") else 1  # interpreter options
    rest = argv[k:]
    if not rest:
        return ["runs python with no script"]
    if rest[0] == "-c":
        try:
            compile(rest[1], "<doc>", "exec")
        except (IndexError, SyntaxError) as exc:
            return [f"python -c: {exc!r}"]
        return []
    if rest[0] != "-m":
        return _script_problems(rest, lenient) + _path_problems(rest[1:])
    if len(rest) < 2:
        return ["python -m with no module"]
    module, args = rest[1], rest[2:]
    if module == "bmctl":
        return _bmctl_problems(args, lenient, mention) + _path_problems(args)
    if module == "pytest":
        paths = [a.split("::")[0] for a in args if "/" in a or a.endswith(".py")]
        return [f"pytest: {p}: no such test file or folder" for p in paths if not (ROOT / p).exists()]
    try:
        found = importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        found = False
    return [] if found else [f"python -m {module}: no such module"]


def command_problems(shown: Shown) -> list[str]:
    """What in ``shown`` no longer parses or names a repository file that is not there ([] if nothing)."""
    try:
        steps = _steps(shown.text)
    except ValueError as exc:
        return [f"cannot be read as a shell line: {exc}"]
    problems = []
    for words in steps:
        while words and (re.match(r"[A-Za-z_]\w*=", words[0]) or words[0] == "nice"):
            if words[0] == "nice" and len(words) > 2 and words[1] == "-n":
                words = words[2:]
            elif words[0] == "nice" and len(words) > 1 and re.fullmatch(r"-\d+", words[1]):
                words = words[1:]
            words = words[1:]
        if not words or words[0] not in ("bmctl", "python", "python3"):
            problems.append(f"runs {words[0] if words else 'nothing'!r}, which this check does not read")
            continue
        # python -c CODE: the code is Python, never a sketch
        variants, sketch = ([words[1:]], False) if words[0] != "bmctl" and "-c" in words else _variants(words[1:])
        for argv in variants:
            if words[0] == "bmctl":
                found = _bmctl_problems(argv, sketch, shown.inline) + _path_problems(argv)
            else:
                found = _python_problems(argv, sketch, shown.inline)
            problems += [p for p in found if p not in problems]
    return problems


def test_the_docs_show_commands_of_every_kind():
    assert len(SHOWN) > 200, len(SHOWN)
    firsts = {s.text.split()[0] for s in SHOWN}
    assert {"bmctl", "python", "nice", "$"} <= firsts, firsts
    assert sum(not s.inline for s in SHOWN) > 50 and sum(s.inline for s in SHOWN) > 100
    subcommands = {s.text.split()[1] for s in SHOWN if s.text.startswith("bmctl ")}
    assert set(COMMANDS) <= subcommands, set(COMMANDS) - subcommands


@pytest.mark.parametrize("shown", SHOWN, ids=[f"{s.where} {' '.join(s.text.split()[:3])}" for s in SHOWN])
def test_doc_command_parses_and_its_files_exist(shown):
    problems = command_problems(shown)
    assert not problems, f"{shown.where}: {shown.text!r}:\n" + "\n".join(problems)


FAKE = ROOT / "docs" / "fake.md"  # never written: the text is given


def test_commands_are_found_in_code_blocks_indented_blocks_and_inline_spans():
    text = ("# Title\n\nRun `bmctl simulate models/alni-1to1-300rpm-lab.toml\n--seed 1` here, and `bmctl`'s help.\n\n"
            "```bash\nbmctl trial scenarios/trial-mismatch.toml \\\n  --seed 2   # a comment\n"
            "echo not a command\n$ bmctl card show my-mill.toml\n```\n\n"
            "```python\nbmctl = 1\n```\n\n"
            "    nice -n 5 python benchmarks/fuzz.py --cases 2\n\n`python -m pytest tests/estimate/`, `plain code`\n")
    assert shown_commands(FAKE, text + "\n    python benchmarks/fuzz.py \\\n        --cases 3\n") == [
        Shown("docs/fake.md:3", "bmctl simulate models/alni-1to1-300rpm-lab.toml --seed 1", True),
        Shown("docs/fake.md:4", "bmctl", True),
        Shown("docs/fake.md:7", "bmctl trial scenarios/trial-mismatch.toml --seed 2   # a comment", False),
        Shown("docs/fake.md:10", "$ bmctl card show my-mill.toml", False),
        Shown("docs/fake.md:17", "nice -n 5 python benchmarks/fuzz.py --cases 2", False),
        Shown("docs/fake.md:19", "python -m pytest tests/estimate/", True),
        Shown("docs/fake.md:21", "python benchmarks/fuzz.py --cases 3", False),
    ]


@pytest.mark.parametrize("line, inline, expected", [
    ("bmctl simulate models/alni-1to1-300rpm-lab.toml --no-such-flag", False, "unrecognized arguments"),
    ("bmctl simulat models/alni-1to1-300rpm-lab.toml", False, "invalid choice"),
    ("bmctl simulate --hours 2", False, "required"),
    ("bmctl simulate models/alni-1to1-300rpm-lab.toml --hours two", False, "--hours"),
    ("bmctl simulate models/no-such-card.toml", False, "models/no-such-card.toml, which is not in the repository"),
    ("bmctl trial scenarios/nowhere.toml --seed 1", True, "scenarios/nowhere.toml, which is not in the repository"),
    ("bmctl campaign advise run1 --jsonn", True, "unrecognized arguments"),
    ("bmctl campaign advise run1 --js", True, "unrecognized arguments"),  # an abbreviation is not the option
    ("python benchmarks/hidden_mills.py --results-nam x", True, "unrecognized arguments"),
    ("bmctl trial SCENARIO.toml [--sed N]", True, "unrecognized arguments"),
    ("bmctl design MODEL.toml --target d50_um=40:50 [--objective target|fastest]", False, "invalid choice"),
    ("bmctl <command> --hlep", True, "unrecognized arguments"),
    ("bmctl campaign status run1; bmctl campaign reprot run1", False, "invalid choice"),
    ("bmctl campaign status run1 | sort; ls", False, "runs 'ls'"),
    ("python benchmarks/no_such_benchmark.py", True, "no such script"),
    ("python benchmarks/fidelity_table.py --particles many", True, "refused"),
    ("nice python benchmarks/fidelity_table.py --no-such-flag", False, "refused"),
    ("python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,ZZ", True, "unknown mill(s) ZZ"),
    ("python benchmarks/hidden_mills.py --mills benchmarks/mills-nowhere.toml", True, "mills-nowhere.toml"),
    ("python benchmarks/hidden_mills.py ... --sample-evry-h H", True, "refused"),
    ("python -m pytest tests/no_such_test.py -q", False, "no such test file"),
    ("python -m bmctl.no_such_module", True, "no such module"),
    ("python -m bmctl simulate --particels 10", False, "unrecognized arguments"),
    ("python -c 'print(('", False, "SyntaxError"),
    ("bmctl campaign log run1 --note \"unclosed", False, "cannot be read"),
])
def test_a_broken_doc_command_is_reported(line, inline, expected):
    problems = command_problems(Shown("docs/fake.md:1", line, inline))
    assert any(expected in p for p in problems), problems


@pytest.mark.parametrize("line, inline", [
    ("bmctl campaign sample DIR --at-h T FILE", False),  # placeholders pass any type
    ("bmctl trial SCENARIO.toml --campaign [--out DIR] [--seed N]", True),
    ("bmctl measure IMAGE... [--out particles.csv] [--um-per-px X | --scale-bar-um L]", False),
    ("bmctl <command> --help", True),
    ("bmctl campaign", True),  # a subcommand named in prose
    ("bmctl simulate my-mill.toml --hours 2 --out models/written-here", False),  # --out is written, not read
    ("python benchmarks/measure_accuracy.py PART --table", False),
    ("python -X importtime -m bmctl --help 2>&1 >/dev/null | sort -t'|' -k2 -n | tail", False),
    ("MPLBACKEND=Agg nice -n 5 python benchmarks/fuzz.py --kinds KIND --start SEED --cases 1", False),
])
def test_placeholders_sketches_and_shell_forms_are_accepted(line, inline):
    assert command_problems(Shown("docs/fake.md:1", line, inline)) == []


def test_a_broken_command_in_a_doc_fails_its_test():
    """End to end: a doc page with one good and two broken commands."""
    text = ("```bash\nbmctl simulate models/alni-1to1-300rpm-lab.toml --seed 1\n"
            "bmctl simulate models/alni-1to1-300rpm-lab.toml --sead 1\n```\n\nSee `bmctl trial scenarios/gone.toml`.\n")
    found = {s.where: command_problems(s) for s in shown_commands(FAKE, text)}
    assert found["docs/fake.md:2"] == []
    assert "unrecognized arguments" in found["docs/fake.md:3"][0]
    assert found["docs/fake.md:6"] == ["names scenarios/gone.toml, which is not in the repository"]
    with pytest.raises(AssertionError, match="--sead"):
        test_doc_command_parses_and_its_files_exist(shown_commands(FAKE, text)[1])


def test_the_check_leaves_argparse_and_the_interpreter_as_they_were():
    import os
    import sys

    before = (argparse.ArgumentParser.parse_args, list(sys.path), os.getcwd(), list(sys.argv))
    assert command_problems(Shown("docs/fake.md:1", "python benchmarks/fidelity_table.py --seed 1", True)) == []
    assert command_problems(Shown("docs/fake.md:1", "python benchmarks/fidelity_table.py --bad", True)) != []
    assert (argparse.ArgumentParser.parse_args, list(sys.path), os.getcwd(), list(sys.argv)) == before
