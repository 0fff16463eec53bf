"""Every results file's recorded ``command`` would still run with the current code.

Each ``results/*.json`` records the command that wrote it (results/README.md). Without running any of
a benchmark's work, this checks that the command's script exists, that its arguments parse with the
script's current argument parser (the script runs as ``__main__`` up to its ``parse_args`` and is
stopped there), that every file it names exists in the repository, and that
``benchmarks/regenerate.py`` registers the file with the same command. A command is read as a small
shell subset: ``A && B`` steps of ``VAR=value`` prefixes, ``nice [-n N]``, ``cd DIR``,
``git worktree add --detach DIR COMMIT`` (the commit must be in the repository), ``cp SRC... DST``
and ``python SCRIPT ARGS``; anything else is a failure, never a skip.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import runpy
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from tests.conftest import ROOT, load_benchmark

RESULTS = ROOT / "results"
FILES = sorted(RESULTS.glob("*.json"))
#: options whose value is something the command writes, not a file it reads
OUTPUT_OPTIONS = {"--out", "--figure", "--json"}
#: a token ending in one of these names a file even without a "/"
FILE_SUFFIXES = (".toml", ".json", ".csv", ".py", ".png", ".tif", ".tiff", ".npz", ".sqlite", ".txt")


class _Parsed(BaseException):
    """Raised in place of returning from the script's ``parse_args``: its work never starts."""

    def __init__(self, problems: list[str]):
        super().__init__()
        self.problems = problems


def parse_with_script(script: Path, args: list[str], cwd: Path, after=None) -> list[str]:
    """Run ``script`` as ``python script args`` from ``cwd`` until its argument parser has parsed
    ``args``, then stop it; returns the problems ([] if none). ``after(namespace, script_globals)``,
    called there (the script still ``__main__``), returns further problems."""
    def parsed(parser, parse, script_globals):
        ns = parse()
        return after(ns, script_globals) if after else []

    return run_to_parser(script, args, cwd, parsed)


def script_parser(script: Path, cwd: Path = ROOT):
    """``(parser, script_globals)``: the argument parser ``script`` builds when run as ``python script``
    from ``cwd``, taken at its ``parse_args`` call (nothing parsed, none of its work run), and the
    script's globals there; ``(None, problems)`` when it never gets there."""
    got = []
    problems = run_to_parser(script, [], cwd, lambda parser, parse, g: got.append((parser, g)) or [])
    return got[0] if got else (None, problems)


def run_to_parser(script: Path, args: list[str], cwd: Path, at_parser) -> list[str]:
    """Run ``script`` as ``python script args`` from ``cwd`` up to its ``parse_args`` call and stop it
    there; returns ``at_parser(parser, parse, script_globals)``, the problems found there (``parse()``
    parses as the script would), or why the script never got there."""
    source = script.read_text(encoding="utf-8")
    if "parse_args(" not in source:  # it would run its work at once: never start it here
        return ["has no argument parser (argparse), so its arguments cannot be checked without running it"]
    real = argparse.ArgumentParser.parse_args

    def stop(self, args=None, namespace=None):
        raise _Parsed(at_parser(self, lambda: real(self, args, namespace), sys._getframe(1).f_globals))

    saved = (sys.argv, list(sys.path), set(sys.modules), os.getcwd(), dict(os.environ))
    err = io.StringIO()
    with tempfile.TemporaryDirectory() as scratch:
        os.environ["BMCTL_RESULTS_DIR"] = scratch  # were any work to start, it would write here, never results/
        os.environ["MPLBACKEND"] = "Agg"
        argparse.ArgumentParser.parse_args = stop
        sys.argv = [str(script), *args]
        sys.path.insert(0, str(script.parent))  # as `python script` does
        os.chdir(cwd)
        try:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                runpy.run_path(str(script), run_name="__main__")
        except _Parsed as done:
            return done.problems
        except SystemExit as exc:
            return [f"refused its arguments (exit {exc.code}): {err.getvalue().strip()[-600:]}"]
        except Exception as exc:  # noqa: BLE001 - any failure before the parser is the finding
            return [f"failed before its arguments were parsed: {type(exc).__name__}: {exc}"]
        finally:
            argparse.ArgumentParser.parse_args = real
            sys.argv, sys.path[:] = saved[0], saved[1]
            os.chdir(saved[3])
            os.environ.clear()
            os.environ.update(saved[4])
            bench = ROOT / "benchmarks"
            for name in set(sys.modules) - saved[2]:  # modules imported from benchmarks/ as top-level names
                file = getattr(sys.modules[name], "__file__", None) or ""
                if Path(file).parent == bench:
                    del sys.modules[name]
    return ["ran to the end without reaching its argument parser"]


def _hidden_mills_cases(ns, g: dict) -> list[str]:
    """``--cases`` of benchmarks/hidden_mills.py name mills of ``--mills`` (or of the built-in pool)."""
    if getattr(ns, "noise", False) or getattr(ns, "table", False) or getattr(ns, "figure", None):
        return []
    card = Path(ns.card).resolve() if ns.card else g["CARD"]
    try:
        pool = g["load_mills"](Path(ns.mills).resolve(), card) if ns.mills else g["CASES"] + g["HELD_OUT"]
    except Exception as exc:  # noqa: BLE001
        return [f"--mills {ns.mills}: {type(exc).__name__}: {exc}"]
    known = [c.name for c in pool]
    if ns.cases is None:
        return []
    unknown = [n.strip() for n in ns.cases.split(",") if n.strip() and n.strip() not in known]
    return [f"--cases: unknown mill(s) {', '.join(unknown)} (known: {', '.join(known)})"] if unknown else []


#: checks past the parser that cost no work, by script name
AFTER_PARSE = {"hidden_mills.py": _hidden_mills_cases}


def _commit_exists(commit: str) -> bool:
    r = subprocess.run(["git", "-C", str(ROOT), "cat-file", "-e", f"{commit}^{{commit}}"], capture_output=True)
    return r.returncode == 0


def history_unusable() -> str | None:
    """Why this checkout's git history cannot tell whether a recorded ``git worktree add`` commit
    exists (no git, no repository, a repository git refuses, a shallow clone), or None."""
    import shutil

    if shutil.which("git") is None:
        return "git is not installed"
    r = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--is-shallow-repository"], capture_output=True,
                       text=True)
    if r.returncode != 0:
        return f"git cannot read this checkout's history ({r.stderr.strip().splitlines()[-1] if r.stderr.strip() else 'no repository'})"
    if r.stdout.strip() == "true":
        return "a shallow clone: older commits are not here"
    return None


def command_problems(command) -> list[str]:
    """What stops ``command`` (run from the repository root) from running with the current code;
    [] when nothing does. Nothing of the benchmark's work is run."""
    if not isinstance(command, str) or not command.strip():
        return [f"no command recorded (got {command!r})"]
    lex = shlex.shlex(command, posix=True, punctuation_chars=True)
    lex.whitespace_split = True
    try:
        tokens = list(lex)
    except ValueError as exc:
        return [f"cannot be read as a shell command: {exc}"]
    steps, cur = [], []
    for t in tokens:
        if t == "&&":
            steps.append(cur)
            cur = []
        elif t and set(t) <= set("();<>|&"):
            return [f"uses the shell construct {t!r}, which this check does not read (use A && B steps)"]
        else:
            cur.append(t)
    steps.append(cur)

    problems: list[str] = []
    cwd, oldpwd = ROOT, ROOT
    worktrees: dict[Path, str] = {}  # made by an earlier step: folder -> commit
    copied: dict[Path, Path] = {}  # file inside a worktree -> the repository file copied there
    pythons = 0

    def resolve(text: str) -> Path:
        text = text.replace("$OLDPWD", str(oldpwd)).replace("$PWD", str(cwd))
        return Path(os.path.normpath(cwd / text))

    def in_worktree(p: Path) -> Path | None:
        return next((w for w in worktrees if p == w or w in p.parents), None)

    def exists(p: Path, folder: bool = False) -> bool:
        w = in_worktree(p)
        if w is not None:
            if p == w or p in copied:
                return True
            rel = p.relative_to(w).as_posix()
            r = subprocess.run(["git", "-C", str(ROOT), "cat-file", "-t", f"{worktrees[w]}:{rel}"],
                               capture_output=True, text=True)
            return r.returncode == 0 and (r.stdout.strip() == "tree" or not folder)
        if p != ROOT and ROOT not in p.parents:
            return False  # outside the repository and not made by an earlier step
        return p.is_dir() if folder else p.exists()

    for step in steps:
        if not step:
            problems.append("has an empty step")
            continue
        while step and "=" in step[0] and not step[0].startswith("-") and step[0].split("=")[0].isidentifier():
            value = step.pop(0).split("=", 1)[1]
            if "/" in value and not exists(resolve(value), folder=True):
                problems.append(f"sets a variable to {value}, which does not exist")
        if step and step[0] == "nice":
            step = step[1:]
            if step and step[0] == "-n":
                step = step[2:]
            elif step and step[0].startswith("-") and step[0][1:].isdigit():
                step = step[1:]
        if not step:
            problems.append("has a step with no program")
            continue
        prog, args = step[0], step[1:]
        if prog == "cd":
            target = resolve(args[0]) if len(args) == 1 else None
            if target is None or not exists(target, folder=True):
                problems.append(f"cd {' '.join(args)}: no such folder")
                continue
            oldpwd, cwd = cwd, target
        elif prog == "git":
            rest = [a for a in args if a != "--detach"]
            if rest[:2] != ["worktree", "add"] or len(rest) != 4:
                problems.append(f"runs 'git {' '.join(args)}', of which this check reads only "
                                "'git worktree add --detach DIR COMMIT'")
                continue
            if not _commit_exists(rest[3]):
                problems.append(f"git worktree add: commit {rest[3]} is not in this repository")
            worktrees[resolve(rest[2])] = rest[3]
        elif prog == "cp":
            if len(args) < 2 or any(a.startswith("-") for a in args):
                problems.append(f"cp {' '.join(args)}: this check reads only 'cp SRC... DST'")
                continue
            dst = resolve(args[-1])
            for src_text in args[:-1]:
                src = resolve(src_text)
                if not exists(src) or in_worktree(src) is not None:
                    problems.append(f"cp: {src_text}: no such file in the repository")
                    continue
                into = dst / src.name if exists(dst, folder=True) else dst
                if not exists(into.parent, folder=True):
                    problems.append(f"cp: {args[-1]}: no such folder")
                    continue
                copied[into] = src
        elif prog in ("python", "python3"):
            pythons += 1
            if not args or args[0].startswith("-"):
                problems.append(f"runs '{prog} {' '.join(args)}': this check reads only 'python SCRIPT ARGS'")
                continue
            script = resolve(args[0])
            if script in copied:
                script = copied[script]
            elif in_worktree(script) is not None:
                problems.append(f"{args[0]}: a script of an older checkout, which this check cannot parse")
                continue
            if not script.is_file() or ROOT not in script.parents:
                problems.append(f"{args[0]}: no such script in the repository")
                continue
            wanted = []
            for k, a in enumerate(args[1:], start=1):
                value = a.split("=", 1)[1] if a.startswith("--") and "=" in a else a
                if value.startswith("-") or args[k - 1] in OUTPUT_OPTIONS or a.split("=")[0] in OUTPUT_OPTIONS:
                    continue
                if "/" in value or value.endswith(FILE_SUFFIXES):
                    wanted.append(value)
            missing = [w for w in wanted if not exists(resolve(w)) and not exists(resolve(w), folder=True)]
            problems += [f"{script.name}: names {w}, which does not exist" for w in missing]
            found = parse_with_script(script, args[1:], cwd if in_worktree(cwd) is None else ROOT,
                                      AFTER_PARSE.get(script.name))
            problems += [f"{script.relative_to(ROOT)}: {p}" for p in found]
        else:
            problems.append(f"runs {prog!r}, which this check does not read")
    if not pythons and not problems:
        problems.append("runs no python script")
    return problems


def results_file_problems(path: Path) -> list[str]:
    """What is wrong with the command recorded in results file ``path``."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        return [f"cannot be read: {exc}"]
    if not isinstance(doc, dict):
        return ["is not a JSON object"]
    return command_problems(doc.get("command"))


def test_there_are_results_files():
    assert len(FILES) > 50, FILES


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_recorded_command_still_parses(path):
    command = json.loads(path.read_text(encoding="utf-8")).get("command")
    why = history_unusable() if isinstance(command, str) and "git worktree add" in command else None
    if why is not None:
        pytest.skip(f"its command makes a worktree of an older commit, and {why}")
    problems = results_file_problems(path)
    assert not problems, f"{path.relative_to(ROOT)}: command {json.loads(path.read_text())['command']!r}:\n" + \
        "\n".join(problems)


@pytest.fixture(scope="module")
def regenerate():
    return load_benchmark("regenerate")


def test_regenerate_registers_every_results_file_with_its_command(regenerate):
    registry = {s.name: s.command for s in regenerate.REGISTRY}
    assert len(registry) == len(regenerate.REGISTRY), "a study is registered twice"
    wrong = []
    for path in FILES:
        recorded = json.loads(path.read_text(encoding="utf-8")).get("command")
        if path.stem not in registry:
            wrong.append(f"{path.stem}: not registered (recorded: {recorded})")
        elif registry[path.stem] != recorded:
            wrong.append(f"{path.stem}: registered {registry[path.stem]!r}, recorded {recorded!r}")
    assert not wrong, "\n".join(wrong)
    unwritten = sorted(set(registry) - {p.stem for p in FILES})
    assert not unwritten, f"registered without a results file: {unwritten}"


def test_regenerate_list_shows_every_study_and_its_command(regenerate, capsys):
    assert regenerate.main(["--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    for study in regenerate.REGISTRY:
        assert any(line.split()[0] == study.name and line.endswith(study.command) for line in lines), study.name


def test_registered_commands_parse(regenerate):
    """A registered command that differs from its file's (or has none) is checked here, the rest above."""
    recorded = {p.stem: json.loads(p.read_text(encoding="utf-8")).get("command") for p in FILES}
    problems = [f"{s.name}: {p}" for s in regenerate.REGISTRY if recorded.get(s.name) != s.command
                for p in command_problems(s.command)]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("command, expected", [
    (None, "no command recorded"),
    ("", "no command recorded"),
    ("python benchmarks/no_such_benchmark.py", "no such script"),
    ("python benchmarks/fidelity_table.py --particles 20000 --no-such-flag", "refused its arguments"),
    ("python benchmarks/fidelity_table.py --particles many", "refused its arguments"),
    ("python benchmarks/calibrate_accuracy.py nowhere --workers 2", "refused its arguments"),
    ("python benchmarks/hidden_mills.py --mills benchmarks/mills-nowhere.toml --cases M --results-name x",
     "mills-nowhere.toml, which does not exist"),
    ("python benchmarks/hidden_mills.py --controller controllers/nowhere.toml", "nowhere.toml, which does not exist"),
    ("python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --cases M,ZZ --results-name x",
     "unknown mill(s) ZZ"),
    ("python benchmarks/hidden_mills.py --cases A,B --seed -1", "refused its arguments"),
    ("git worktree add --detach /tmp/base 0000000 && python benchmarks/bench_measure.py --against /tmp/base",
     "commit 0000000 is not in this repository"),
    ("python benchmarks/bench_measure.py --against /tmp/nowhere", "/tmp/nowhere, which does not exist"),
    ("python benchmarks/model_facts.py > out.txt", "shell construct"),
    ("make results", "does not read"),
])
def test_a_broken_command_is_reported(tmp_path, command, expected):
    """The check fails a results file whose command no longer runs (a copy in a temporary folder)."""
    path = tmp_path / "broken.json"
    path.write_text(json.dumps({"command": command, "settings": {}}))
    problems = results_file_problems(path)
    assert any(expected in p for p in problems), problems


def test_a_file_without_a_command_field_is_reported(tmp_path):
    path = tmp_path / "nocommand.json"
    path.write_text(json.dumps({"settings": {}}))
    assert results_file_problems(path) == ["no command recorded (got None)"]


def test_the_check_leaves_argparse_and_the_interpreter_as_they_were():
    before = (argparse.ArgumentParser.parse_args, list(sys.path), os.getcwd(), list(sys.argv))
    assert command_problems("python benchmarks/fidelity_table.py --particles 20000 --seed 2024") == []
    assert command_problems("python benchmarks/fidelity_table.py --bad") != []
    assert (argparse.ArgumentParser.parse_args, list(sys.path), os.getcwd(), list(sys.argv)) == before


def test_a_full_regeneration_leaves_the_manual_studies_to_only(regenerate, monkeypatch):
    """The studies that need an older checkout at /tmp/base run only when named (never run here)."""
    ran = []
    monkeypatch.setattr(regenerate, "run", lambda study: ran.append(study.name) or True)
    assert regenerate.main([]) == 0
    manual = {s.name for s in regenerate.REGISTRY if s.manual}
    assert manual and not manual & set(ran)
    assert set(ran) == {s.name for s in regenerate.REGISTRY} - manual
    ran.clear()
    assert regenerate.main(["--only", "bench_measure"]) == 0 and ran == ["bench_measure"]
