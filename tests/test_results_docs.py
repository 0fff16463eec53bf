"""Numbers in README.md and docs/ are tied to results files, so a doc cannot drift from its data.

Markers (invisible HTML comments around the number as displayed, without its unit):

* ``<!--r:FILE:KEY-->VALUE<!--/r-->``: measured. ``FILE`` is relative to ``results/``; ``KEY`` is a
  dotted path into the JSON (integer parts index lists); for a CSV, ``ROW.COLUMN`` (row index) or
  ``KEYCOL=VALUE.COLUMN``. VALUE must equal the file's value rounded to VALUE's displayed
  decimals (``46.1k`` reads as 46100 shown to 100; ``2.3·10⁻⁴`` and ``4.5e-3`` are understood).
* ``<!--hand-->VALUE<!--/hand-->``: a hand calculation from other (marked) numbers or inputs.
* ``<!--in-->VALUE<!--/in-->``: not measured by bmctl -- an input or setting, a target, a
  constant, or a value quoted from the paper or the literature. Only needed where the number
  would otherwise look measured (see the strictness rule).

Strictness rule (``test_measured_looking_numbers_are_marked``): in the prose of README.md and
docs/*.md -- outside fenced code blocks, inline code, HTML comments, link targets and markers --
a number *looks measured* when it

1. has a decimal point (``1.91``, ``0.114``), or
2. is followed by ``%`` (``61 %``), or
3. touches ``×`` (``2.66×``, ``× 1.5``), or touches ``±`` (``7.61 ± 1.23``), or
4. is followed by a timing unit ``s``, ``ms`` or ``µs`` (``0.8 s``).

Such a number must sit inside one of the three markers. Not counted: section, equation, table
and figure numbers (``Sec. 4.2``, ``eqn 6.1.35``, ``### 5.1`` at the start of a heading), version strings (``0.1.0``, ``Python 3.11``)
and numbers inside words or identifiers (``Dv10``, ``s_um``, ``model-x1.5``). Plain integers
with other units (``300 rpm``, ``12 h``, ``45 µm``) are not counted: they are almost always inputs.
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
REQUIRED = ("bmctl_version", "command", "settings", "created_utc")

# Docs not yet converted to markers: exempt from the strictness check only (their markers, if
# any, are still checked). Each owner removes a file here once its numbers are marked; the set
# is empty at release.
PENDING: set[str] = set()

MARKER = re.compile(r"<!--r:([^:>\s]+):([^>\n]+?)-->(.*?)<!--/r-->", re.S)
HAND = re.compile(r"<!--(hand|in)-->(.*?)<!--/\1-->", re.S)
SUP = str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁺", "0123456789-+")
NUMBER = re.compile(r"^([+-]?)(\d[\d,]*)(?:\.(\d+))?(?:(?:e|E)([+-]?\d+)|[·×]10\^?([+-]?\d+))?(k|M)?$")


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def parse_displayed(text: str) -> tuple[float, float]:
    """(value, half of the last displayed digit's step) of a number as shown in a doc."""
    t = text.strip().replace("−", "-").replace("\u2009", "").replace("\u202f", "").translate(SUP)
    m = NUMBER.match(t)
    if not m:
        raise ValueError(f"not a number as displayed: {text!r}")
    sign, whole, frac, exp_e, exp_dot, suffix = m.groups()
    digits = whole.replace(",", "")
    frac = frac or ""
    exponent = int(exp_e or exp_dot or 0) + {"k": 3, "M": 6, None: 0}[suffix]
    value = float(f"{sign}{digits}.{frac or '0'}") * 10.0 ** exponent
    half_step = 0.5 * 10.0 ** (exponent - len(frac))
    return value, half_step


def _csv_lookup(path: Path, key: str):
    rows = list(csv.DictReader(path.read_text(encoding="utf-8").splitlines()))
    row_part, _, column = key.rpartition(".")
    if "=" in row_part:
        keycol, _, keyval = row_part.partition("=")
        match = [r for r in rows if r.get(keycol) == keyval]
        if len(match) != 1:
            raise KeyError(f"{len(match)} rows with {keycol}={keyval}")
        row = match[0]
    else:
        row = rows[int(row_part)]
    if column not in row:
        raise KeyError(column)
    return row[column]


def resolve(file: str, key: str, root: Path = RESULTS):
    from bmctl.results import lookup

    path = root / file
    if not path.is_file():
        raise FileNotFoundError(f"results/{file} does not exist")
    if path.suffix == ".csv":
        return _csv_lookup(path, key)
    return lookup(json.loads(path.read_text(encoding="utf-8")), key)


def check_marker(file: str, key: str, shown: str, root: Path = RESULTS) -> str | None:
    """None when the marker holds, else what is wrong."""
    try:
        value = resolve(file, key, root)
    except (FileNotFoundError, KeyError, IndexError, ValueError) as exc:
        return f"{file}:{key}: cannot resolve ({exc})"
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            return None if value == shown.strip() else f"{file}:{key}: file has {value!r}, doc shows {shown!r}"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"{file}:{key}: not a number in the file ({value!r})"
    try:
        shown_value, half_step = parse_displayed(shown)
    except ValueError as exc:
        return f"{file}:{key}: {exc}"
    if not math.isfinite(value) or abs(value - shown_value) > half_step * (1 + 1e-9) + 1e-12 * abs(value):
        return f"{file}:{key}: file has {value!r}, doc shows {shown.strip()!r}"
    return None


# ------------------------------------------------------------------ strictness
FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.S | re.M)
INLINE_CODE = re.compile(r"`[^`\n]*`")
COMMENT_SPAN = re.compile(r"<!--(r:[^>]*|hand|in)-->.*?<!--/(r|hand|in)-->", re.S)
COMMENT = re.compile(r"<!--.*?-->", re.S)
LINK_TARGET = re.compile(r"\]\([^)]*\)")
URL = re.compile(r"https?://\S+")
# a number not glued to a word, identifier or another number on its left
TOKEN = re.compile(r"(?<![\w.\-/^=≤≥<>])(?<!\w-)([+\-−]?\d[\d,]*(?:\.\d+)*(?:·10[⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁺]+)?)(?![\w])")
REF_BEFORE = re.compile(r"(Sec\.|Section|Secs\.|eqns?\.?|Eqs?\.|Eqn\.?|Fig\.|Figs\.|Table|Tab\.|Python|version|v|"
                        r"Stegun|ISO|numpy|scipy|numba|casadi|pydantic|pytest|^#{1,6})\s*$", re.I)
TIME_UNIT = re.compile(r"^\s*(s|ms|µs|us)\b")


def prose(text: str) -> str:
    for pattern in (FENCE, COMMENT_SPAN, COMMENT, INLINE_CODE, LINK_TARGET, URL):
        text = pattern.sub(lambda m: " " * len(m.group(0)) if "\n" not in m.group(0)
                           else "\n" * m.group(0).count("\n"), text)
    return text


def measured_looking(text: str) -> list[tuple[int, str]]:
    """(line number, token with context) for every unmarked number that looks measured."""
    found = []
    for lineno, line in enumerate(prose(text).splitlines(), 1):
        for m in TOKEN.finditer(line):
            tok = m.group(1)
            before, after = line[:m.start(1)], line[m.end(1):]
            if REF_BEFORE.search(before):
                continue
            if tok.count(".") >= 2:  # a version or a dotted reference
                continue
            looks = ("." in tok or after.lstrip().startswith("%") or after.lstrip().startswith(("×", "±"))
                     or before.rstrip().endswith(("×", "±")) or TIME_UNIT.match(after) is not None)
            if looks:
                found.append((lineno, line[max(0, m.start(1) - 25):m.end(1) + 12].strip()))
    return found


# ------------------------------------------------------------------ tests
def _markers():
    out = []
    for doc in DOCS:
        text = doc.read_text(encoding="utf-8")
        for m in MARKER.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            out.append(pytest.param(m.group(1), m.group(2), m.group(3), id=f"{_rel(doc)}:{line}:{m.group(2)}"))
    return out


MARKERS = _markers()


@pytest.mark.parametrize("file,key,shown", MARKERS or [pytest.param(None, None, None, marks=pytest.mark.skip("no markers yet"))])
def test_marked_number_matches_results_file(file, key, shown):
    problem = check_marker(file, key, shown)
    assert problem is None, problem


@pytest.mark.parametrize("doc", DOCS, ids=_rel)
def test_hand_and_input_markers_hold_numbers(doc):
    bad = []
    for m in HAND.finditer(doc.read_text(encoding="utf-8")):
        try:
            parse_displayed(m.group(2))
        except ValueError:
            bad.append(m.group(0))
    assert not bad, f"{_rel(doc)}: markers without a plain number: {bad}"


@pytest.mark.parametrize("doc", DOCS, ids=_rel)
def test_measured_looking_numbers_are_marked(doc):
    if _rel(doc) in PENDING:
        pytest.skip("doc not yet converted to results markers (PENDING)")
    found = measured_looking(doc.read_text(encoding="utf-8"))
    listing = "\n".join(f"  {_rel(doc)}:{n}: ...{ctx}..." for n, ctx in found)
    assert not found, f"unmarked measured-looking numbers (wrap in <!--r:...-->, <!--hand--> or <!--in-->):\n{listing}"


def test_pending_lists_only_existing_docs():
    missing = PENDING - {_rel(d) for d in DOCS}
    assert not missing, f"PENDING names docs that do not exist: {sorted(missing)}"


def test_results_files_carry_provenance():
    bad = []
    for path in sorted(RESULTS.glob("*.json")):
        record = json.loads(path.read_text(encoding="utf-8"))
        lacking = [k for k in REQUIRED if k not in record]
        if lacking:
            bad.append(f"{path.name}: lacks {lacking}")
    for path in sorted(RESULTS.glob("*.csv")):
        sidecar = path.with_suffix(".json")
        if not sidecar.is_file():
            bad.append(f"{path.name}: no {sidecar.name} with its provenance")
    assert not bad, "\n".join(bad)


# ------------------------------------------------------------------ the checker itself
@pytest.mark.parametrize("shown,value,ok", [
    ("1.8", 1.84, True), ("1.8", 1.86, False), ("1.91", 1.905, True), ("12", 11.6, True),
    ("12", 12.6, False), ("−0.5", -0.52, True), ("20,000", 20000, True), ("46.1k", 46130, True),
    ("46.1k", 46200, False), ("2.3·10⁻⁴", 2.31e-4, True), ("2×10⁻⁴", 2.4e-4, True), ("4.5e-3", 4.6e-3, False),
])
def test_checker_rounds_to_displayed_decimals(tmp_path, shown, value, ok):
    (tmp_path / "x.json").write_text(json.dumps({"a": {"b": [value]}}), encoding="utf-8")
    assert (check_marker("x.json", "a.b.0", shown, tmp_path) is None) is ok
    assert check_marker("x.json", "a.c", shown, tmp_path) is not None  # missing key fails
    assert check_marker("missing.json", "a", shown, tmp_path) is not None  # missing file fails


def test_checker_reads_csv(tmp_path):
    (tmp_path / "t.csv").write_text("card,d50_um\nlab,41.23\n400,93.5\n", encoding="utf-8")
    assert check_marker("t.csv", "card=lab.d50_um", "41.2", tmp_path) is None
    assert check_marker("t.csv", "1.d50_um", "93.5", tmp_path) is None
    assert check_marker("t.csv", "card=lab.d50_um", "41.3", tmp_path) is not None


@pytest.mark.parametrize("text,n", [
    ("error 1.91 % at 12 h", 1), ("at 300 rpm for 12 h, seed 0", 0), ("γ above truth in 16 of 20, rms 61 %", 1),
    ("grows 2.66× by 2 h", 1), ("Sec. 4.2 claims", 0), ("eqn 6.1.35 and version 0.1.0", 0),
    ("7.61 ± 1.23 %", 2), ("takes 40 s", 1), ("`r_mean = 0.05`", 0), ("<!--in-->0.05<!--/in--> target", 0),
    ("<!--r:a.json:b-->1.5<!--/r--> %", 0), ("Dv10 and s_um", 0), ("```\n1.5 %\n```", 0), ("![x](a1.5.png)", 0),
    ("### 5.1 Synthetic images", 0), ("### 5.1 Synthetic images, 1.5 % off", 1),
])
def test_strictness_rule(text, n):
    assert len(measured_looking(text)) == n, measured_looking(text)


#: a table row's verdict on its bound: "≤ N unit ...: met" or "...: not met" (the first such in the row)
CLAIM = re.compile(r"≤\s*(?:<!--in-->)?([0-9.,]+)(?:<!--/in-->)?[^|:]*?:\s*(not met|met)\b")
FIRST_MEASURED = re.compile(r"<!--r:[^>]*-->([^<]+)<!--/r-->")


def met_claims(text: str) -> list[tuple[int, float, float, bool]]:
    """(line, measured, bound, claimed met) of every table row that says whether it meets its bound
    ("≤ N ...: met" / "not met"); measured is the row's first marked number."""
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.lstrip().startswith("|"):
            continue
        claim, measured = CLAIM.search(line), FIRST_MEASURED.search(line)
        if claim and measured:
            out.append((n, parse_displayed(measured.group(1))[0], parse_displayed(claim.group(1))[0],
                        claim.group(2) == "met"))
    return out


@pytest.mark.parametrize("doc", DOCS, ids=_rel)
def test_met_claims_agree_with_their_numbers(doc):
    """A row that says its target is met (or not) says so of the number it shows: a rerun that moves
    the number across the bound must change the words too."""
    wrong = [f"{_rel(doc)}:{n}: {value:g} against <= {bound:g} claimed {'met' if met else 'not met'}"
             for n, value, bound, met in met_claims(doc.read_text(encoding="utf-8")) if (value <= bound) != met]
    assert not wrong, "\n".join(wrong)


def test_met_claims_are_found():
    rows = ["| a | <!--r:f.json:x-->5.2<!--/r--> ms | 1.4 | ≤ <!--in-->5<!--/in--> ms: not met on this machine |",
            "| b | <!--r:f.json:y-->60.0<!--/r--> s | 1.0 | ≤ <!--in-->90<!--/in--> s wall on two idle cores: met, more |",
            "| c | <!--r:f.json:z-->12.6<!--/r--> | 14.8 | ≤ <!--in-->10<!--/in--> s: met in wall time |",
            "prose ≤ <!--in-->10<!--/in--> s: met <!--r:f.json:z-->12.6<!--/r-->"]
    assert met_claims("\n".join(rows)) == [(1, 5.2, 5.0, False), (2, 60.0, 90.0, True), (3, 12.6, 10.0, True)]
