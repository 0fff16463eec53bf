"""Hostile-input cases for the ``bmctl`` CLI and a checker of what it does with them.

Shared by the seeded property test (tests/test_fuzz.py, Hypothesis draws the case seeds) and
the long run (benchmarks/fuzz.py, each case in a forked subprocess). A case is a command line
built around one mutated input -- a model card, a schedule, a scenario, a controller, a
particle table, a micrograph, a flag, a campaign command or database, or a damaged file of an
interrupted trial -- plus the names an error message about it may use.
:func:`classify` sorts what the CLI did into the outcomes of docs/reliability.md:

``clean``            exit 2, one stderr line naming the file, flag or field
``accepted-ok``      exit 0, every output within physical bounds
``accepted-nonsense`` exit 0, but the printed summary is not finite or physical
``wrote-nonsense``   exit 0, an output file outside physical bounds
``traceback``        any other exception or exit status
``hang``             the per-case time limit ran out
``unnamed``          exit 2 without naming the file, flag or field (or more than one line, or a
                     line over 1,000 characters)
``unsafe``           a file written outside the case's ``out`` folder, the text of a file the
                     command was not given in any output, or markup from input in an HTML output
"""

from __future__ import annotations

import atexit
import csv
import functools
import io
import json
import math
import random
import shutil
import sqlite3
import struct
import tempfile
import tomllib
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CARDS = sorted(p for p in (ROOT / "models").glob("*.toml") if not p.name.endswith(".moments.toml"))
CONTROLLERS = sorted((ROOT / "controllers").glob("*.toml"))
OUTCOMES = ("clean", "accepted-ok", "accepted-nonsense", "wrote-nonsense", "traceback", "hang", "unnamed", "unsafe")
#: physical bounds every output must keep
T_MIN_C, T_MAX_C = -60.0, 4000.0  # the vial: -50 C readings at the lowest, a melting point at the highest
AL_MELTING_C = 660.3  # the shipped cards are Al-Ni powders: no output may be hotter
S_MIN_UM, S_MAX_UM = 1e-3, 1e4  # 1 nm .. 10 mm
EXTREMES = (0, -1, 1e-300, 1e300, float("nan"), float("inf"), float("-inf"), 10**30, -1e-320, 1e-320)
TINY = dict(hours="0.2", particles="200")


# --- a tiny TOML writer (tomllib reads; the mutated data must be written back) -------------------

def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_dumps(data: dict) -> str:
    """TOML text of ``data`` (scalars first, then tables and arrays of tables)."""
    lines, tables = [], []
    for k, v in data.items():
        if isinstance(v, dict) and v and all(not isinstance(x, dict) for x in v.values()):
            tables.append((k, v))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            tables.append((k, v))
        else:
            lines.append(f"{json.dumps(k)} = {_value(v)}")
    for k, v in tables:
        if isinstance(v, dict):
            lines.append(f"\n[{json.dumps(k)}]")
            lines += [f"{json.dumps(a)} = {_value(b)}" for a, b in v.items()]
        else:
            for item in v:
                lines.append(f"\n[[{json.dumps(k)}]]")
                lines += [f"{json.dumps(a)} = {_value(b)}" for a, b in item.items()]
    return "\n".join(lines) + "\n"


# --- mutations ------------------------------------------------------------------------------------

def _leaves(data, prefix=()):
    """(path, value) of every scalar or list leaf of a parsed TOML document."""
    for k, v in data.items():
        if isinstance(v, dict):
            yield from _leaves(v, prefix + (k,))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for i, item in enumerate(v):
                yield from _leaves(item, prefix + (k, i))
        else:
            yield prefix + (k,), v


def _set(data, path, value, delete=False):
    d = data
    for k in path[:-1]:
        d = d[k]
    if delete:
        del d[path[-1]]
    else:
        d[path[-1]] = value


def swap_value(rng: random.Random, v):
    """A replacement of another type or an extreme number."""
    kind = rng.choice(["extreme", "extreme", "string", "bool", "list", "table", "scale"])
    if kind == "extreme":
        return rng.choice(EXTREMES)
    if kind == "string":
        return str(v) if rng.random() < 0.7 else rng.choice(["", "yes", "1e9", "abc"])
    if kind == "bool":
        return rng.choice([True, False])
    if kind == "list":
        return [v, v]
    if kind == "table":
        return {"x": 1}
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return type(v)(v * rng.choice([1e3, 1e-3, 10, -1, 0.5, 2]))
    return rng.choice(EXTREMES)


def mutate_toml(rng: random.Random, text: str) -> tuple[bytes, list[str], str]:
    """One mutation of a TOML file; returns (bytes, field names it touched, a label)."""
    data = tomllib.loads(text)
    leaves = list(_leaves(data))
    op = rng.choice(["delete", "swap", "swap", "swap", "truncate", "garbage", "drop-table", "unknown-key", "swap2",
                     "deep", "odd-key", "long-text"])
    if op == "deep":  # nested arrays or inline tables, deeper than any settings file
        depth = rng.choice([65, 1000, 100_000])
        value = deep_toml_value(depth) if rng.random() < 0.7 else "{a = " * depth + "1" + "}" * depth
        return f"zz = {value}\n{text}".encode(), ["nested"], f"a value nested {depth} deep"
    if op == "odd-key":  # a key holding a newline, a control character or 200,000 characters
        key = rng.choice(['"bo\\ngus"', '"a\\rb"', '"\\u001b[31mred"', '"x\\u2028y"', json.dumps("k" * 200_000)])
        return f"{key} = 1\n{text}".encode(), ["unknown field"], f"odd key {key[:12]}"
    if op == "long-text":  # a text field (a name) of 200,000 characters, or one with a newline
        strings = [(pth, v) for pth, v in leaves if isinstance(v, str)]
        if strings:
            pth, _ = rng.choice(strings)
            nv = rng.choice(["x" * 200_000, "a\nb", "tab\there", "\x1b[2J"])
            _set(data, pth, nv)
            return toml_dumps(data).encode(), [str(pth[-1])], f"{'.'.join(map(str, pth))} = {nv[:8]!r}..."
        op = "swap"
    if op == "truncate":
        cut = rng.random()
        raw = text.encode()
        return raw[: int(cut * len(raw))], [], f"truncated@{cut:.2f}"
    if op == "garbage":
        n = rng.choice([0, 1, 17, 300])
        return bytes(rng.getrandbits(8) for _ in range(n)), [], f"garbage{n}"
    if op == "drop-table":
        tabs = [k for k, v in data.items() if isinstance(v, (dict, list)) and not isinstance(v, str)]
        if tabs:
            t = rng.choice(tabs)
            del data[t]
            return toml_dumps(data).encode(), [t], f"drop[{t}]"
    if op == "unknown-key":
        tabs = [k for k, v in data.items() if isinstance(v, dict)] or [None]
        t = rng.choice(tabs)
        (data[t] if t else data)["bogus_key"] = 1.0
        return toml_dumps(data).encode(), ["bogus_key"], "unknown-key"
    names, labels = [], []
    for _ in range(2 if op == "swap2" else 1):
        path, v = rng.choice(leaves)
        if op == "delete":
            _set(data, path, None, delete=True)
            labels.append(f"del {'.'.join(map(str, path))}")
        else:
            nv = swap_value(rng, v)
            _set(data, path, nv)
            labels.append(f"{'.'.join(map(str, path))}={_value(nv)[:20]}")
        names.append(str(path[-1]))
    return toml_dumps(data).encode(), names, "; ".join(labels)


def base_table(rng: random.Random, n: int = 60, layout: str = "s_um,r") -> list[list[str]]:
    """A plausible particle table: sizes ~ 40 um, aspect ratios ~ 0.05."""
    s = [max(1.0, rng.gauss(40, 8)) for _ in range(n)]
    r = [min(0.9, abs(rng.gauss(0.05, 0.03))) for _ in range(n)]
    if layout == "s_um,r":
        return [["s_um", "r"]] + [[f"{a:.4g}", f"{b:.4g}"] for a, b in zip(s, r)]
    return [["area_um2", "perimeter_um"]] + [[f"{math.pi * a * a / 4:.5g}", f"{math.pi * a / (1 - b):.5g}"]
                                             for a, b in zip(s, r)]


def mutate_table(rng: random.Random) -> tuple[bytes, list[str], str]:
    """A particle table CSV with one hostile change."""
    rows = base_table(rng, rng.choice([3, 59, 200]), rng.choice(["s_um,r", "area_um2,perimeter_um"]))
    op = rng.choice(["value", "value", "value", "column", "garbage", "truncate", "empty", "header-only", "ok"])
    label = op
    if op == "value":
        i, j = rng.randrange(1, len(rows)), rng.randrange(2)
        v = rng.choice(["1e308", "1e-320", "1e-300", "-5", "0", "nan", "inf", "abc", "", "1e30", "0.9999999",
                        "1", "5e-324", "1e-6", "3e4"])
        rows[i][j] = v
        label = f"row{i + 1}.{rows[0][j]}={v}"
    elif op == "column":
        j = rng.randrange(2)
        rows = [[r[1 - j]] for r in rows]
        label = "missing column"
    elif op == "garbage":
        return bytes(rng.getrandbits(8) for _ in range(rng.choice([5, 500]))), [], "garbage"
    elif op == "empty":
        return b"", [], "empty"
    elif op == "header-only":
        rows = rows[:1]
    text = "\n".join(",".join(r) for r in rows) + "\n"
    if op == "truncate":
        cut = rng.random()
        text = text[: int(cut * len(text))]
        label = f"truncated@{cut:.2f}"
    return text.encode(), ["s_um", "r", "area_um2", "perimeter_um", "row", "column"], label


def _png(w: int, h: int, pixels: bytes | None = None) -> bytes:
    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    raw = pixels if pixels is not None else b"".join(b"\0" + bytes(w) for _ in range(min(h, 64)))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def _tiff_header(w: int, h: int) -> bytes:
    """A little-endian TIFF whose header claims w x h 8-bit pixels (strip far beyond the file)."""
    entries = [(256, 4, 1, w), (257, 4, 1, h), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1),
               (273, 4, 1, 8 + 2 + 12 * 8 + 4), (277, 3, 1, 1), (278, 4, 1, h), (279, 4, 1, w * h & 0xFFFFFFFF)]
    ifd = struct.pack("<H", len(entries)) + b"".join(struct.pack("<HHII", *e) for e in entries) + b"\0\0\0\0"
    return b"II*\x00" + struct.pack("<I", 8) + ifd + bytes(64)


def synthetic_micrograph(rng: random.Random, size: int = 96) -> bytes:
    """A small gray PNG with a few bright discs on a dark background."""
    img = np.full((size, size), 20, np.uint8)
    yy, xx = np.mgrid[:size, :size]
    for _ in range(6):
        cy, cx, rad = rng.randrange(10, size - 10), rng.randrange(10, size - 10), rng.randrange(4, 9)
        img[(yy - cy) ** 2 + (xx - cx) ** 2 <= rad * rad] = 220
    raw = b"".join(b"\0" + img[i].tobytes() for i in range(size))
    return _png(size, size, raw)


@functools.lru_cache(maxsize=1)
def bomb_tiff() -> bytes:
    """A ~150 kB zlib-compressed TIFF of 12,000 x 12,000 px (a decompression bomb: 144 Mpx)."""
    import tifffile

    buf = io.BytesIO()
    tifffile.imwrite(buf, np.zeros((12_000, 12_000), np.uint8), compression="zlib")
    return buf.getvalue()


def mutate_image(rng: random.Random) -> tuple[bytes, str, str]:
    """(bytes, suffix, label) of a hostile micrograph."""
    op = rng.choice(["garbage", "tiny", "huge-png", "huge-tiff", "truncated", "ok", "ok", "blank", "bomb"])
    if op == "bomb":
        return bomb_tiff(), ".tif", op
    if op == "garbage":
        return bytes(rng.getrandbits(8) for _ in range(rng.choice([0, 10, 4000]))), rng.choice([".png", ".tif"]), op
    if op == "tiny":
        return _png(2, 2, b"\0\0\0\0\0\0"), ".png", op
    if op == "huge-png":
        return _png(100_000, 100_000, b"\0" * 10), ".png", op
    if op == "huge-tiff":
        return _tiff_header(rng.choice([60_000, 2**31 - 1]), rng.choice([60_000, 2**31 - 1])), ".tif", op
    ok = synthetic_micrograph(rng)
    if op == "truncated":
        return ok[: rng.randrange(8, len(ok) - 1)], ".png", op
    if op == "blank":
        return _png(64, 64), ".png", op
    return ok, ".png", op


# --- cases ------------------------------------------------------------------------------------------

@dataclass
class Case:
    """One command line and the files it reads; ``names``: what an error may name."""

    kind: str
    label: str
    argv: list[str]
    files: dict[str, bytes] = field(default_factory=dict)
    names: list[str] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)
    out: str = "out"
    t_max_c: float = AL_MELTING_C  # the hottest output allowed
    #: commands run before ``argv`` (each must exit 0 for the next to run; the first other exit is the outcome)
    pre: list[list[str]] = field(default_factory=list)
    #: builds what the case starts from under its folder (a copied campaign or trial, then damaged)
    setup: Callable[[Path], None] | None = None
    #: further checks of the ``out`` folder after exit 0: a list of problems (empty: sane)
    verify: Callable[[Path], list[str]] | None = None
    #: text in a file the command was not given: it must appear in no output (stdout, stderr, files)
    sentinel: str | None = None
    #: the case folder's files outside ``out`` once written (what the command may not add to)
    before: frozenset | None = None

    def write(self, folder: Path) -> list[str]:
        """Write the case's files under ``folder``; returns argv with paths made absolute."""
        for name, data in self.files.items():
            (folder / name).parent.mkdir(parents=True, exist_ok=True)
            (folder / name).write_bytes(data)
        if self.setup is not None:
            self.setup(folder)
        self.before = frozenset(outside_out(folder))
        return self._abs(self.argv, folder)

    def _abs(self, argv: list[str], folder: Path) -> list[str]:
        return [a.replace("@", str(folder) + "/") if a.startswith("@") else a for a in argv]

    def commands(self, folder: Path) -> list[list[str]]:
        """Every command line of the case, in order (``pre`` then ``argv``), paths made absolute."""
        return [self._abs(a, folder) for a in self.pre] + [self._abs(self.argv, folder)]


def _card(rng: random.Random) -> Path:
    return rng.choice(CARDS)


def _schedule_text(rng: random.Random) -> str:
    segs = [{"hours": rng.choice([0.05, 0.1]), "rpm": rng.choice([0, 200, 300, 400])} for _ in range(rng.randint(1, 3))]
    segs[0]["rpm"] = 300
    return toml_dumps({"name": "fz", "segment": segs})


SCENARIO_BASE = """model = "{model}"
hours = 0.5
[scenario]
name = "fz"
description = "fuzz base"
[controller]
config = "{controller}"
[plant]
particles = 200
[sampling]
every_h = 0.5
particles = 40
[estimator]
particles = 60
"""


def make_case(kind: str, seed: int) -> Case:
    """The case ``seed`` of ``kind`` (card, schedule, scenario, controller, table, image, flags)."""
    rng = random.Random(f"{kind}:{seed}")
    out = "@out"
    if kind == "card":
        src = _card(rng)
        data, names, label = mutate_toml(rng, src.read_text(encoding="utf-8"))
        cmd = rng.choice(["simulate", "simulate", "card", "whatif", "estimate"])
        files = {"card.toml": data}
        if cmd == "simulate":
            argv = ["simulate", "@card.toml", "--hours", TINY["hours"], "--particles", TINY["particles"],
                    "--every", "0.1", "--out", out, "--no-progress"]
        elif cmd == "card":
            argv = ["card", "show", "@card.toml"]
        elif cmd == "whatif":
            files["s.toml"] = _schedule_text(rng).encode()
            argv = ["whatif", "@card.toml", "@s.toml", "--seeds", "1", "--particles", "200", "--out", out]
        else:
            files["a.csv"] = "\n".join(",".join(r) for r in base_table(rng)).encode()
            argv = ["estimate", "@card.toml", "--samples", "@a.csv", "--times", "0.2", "--particles", "200",
                    "--out", out + "/e.csv"]
        hot = T_MAX_C if ("powder" in label or "validity" in label) else AL_MELTING_C
        return Case(kind, f"{src.stem}: {label} [{cmd}]", argv, files, names + ["card.toml"], t_max_c=hot)
    if kind == "schedule":
        data, names, label = mutate_toml(rng, _schedule_text(rng))
        cmd = rng.choice(["simulate", "whatif"])
        if cmd == "simulate":
            argv = ["simulate", str(_card(rng)), "--schedule", "@s.toml", "--particles", "200", "--every", "0.1",
                    "--out", out, "--no-progress"]
        else:
            argv = ["whatif", str(_card(rng)), "@s.toml", "--seeds", "1", "--particles", "200", "--out", out]
        return Case(kind, f"schedule: {label} [{cmd}]", argv, {"s.toml": data}, names + ["s.toml", "--schedule"])
    if kind == "scenario":
        ctrl = rng.choice([c for c in CONTROLLERS if c.stem.startswith("recipe")])
        text = SCENARIO_BASE.format(model=_card(rng).relative_to(ROOT), controller=ctrl.relative_to(ROOT))
        data, names, label = mutate_toml(rng, text)
        return Case(kind, f"scenario: {label}", ["trial", "@sc.toml", "--out", out, "--no-progress"],
                    {"sc.toml": data}, names + ["sc.toml"], env={"BMCTL_BUDGET_CPU_H": "1e-3"})
    if kind == "controller":
        src = rng.choice(CONTROLLERS)
        data, names, label = mutate_toml(rng, src.read_text(encoding="utf-8"))
        # the solver-backed commands are refused by a tiny work budget unless the input is bad first
        argv = ["design", str(_card(rng)), "--target", "s_mean_um=30", "--hours", "1", "--controller", "@c.toml",
                "--out", out]
        return Case(kind, f"{src.stem}: {label} [design]", argv, {"c.toml": data}, names + ["c.toml", "--controller"],
                    env={"BMCTL_BUDGET_CPU_H": "1e-9"})
    if kind == "table":
        data, names, label = mutate_table(rng)
        cmd = rng.choice(["measure", "estimate"])
        if cmd == "measure":
            argv = ["measure", "@t.csv", "--out", out + "/m.csv"]
        else:
            argv = ["estimate", str(_card(rng)), "--samples", "@t.csv", "--times", "0.5", "--particles", "200",
                    "--out", out + "/e.csv"]
        return Case(kind, f"table: {label} [{cmd}]", argv, {"t.csv": data}, names + ["t.csv"])
    if kind == "image":
        data, suffix, label = mutate_image(rng)
        flags = rng.choice([["--um-per-px", "0.5"], ["--um-per-px", "1e-300"], ["--um-per-px", "1e9"],
                            ["--um-per-px", "0.5"], ["--um-per-px", "nan"], []])
        argv = ["measure", f"@img{suffix}", "--out", out + "/m.csv", *flags]
        return Case(kind, f"image: {label} {' '.join(flags)}", argv, {f"img{suffix}": data},
                    ["img" + suffix, "--um-per-px", "--scale-bar-um"])
    if kind == "flags":
        return _flag_case(rng, out)
    if kind == "campaign":
        return _campaign_case(rng)
    if kind == "resume":
        return _resume_case(rng)
    if kind in SECOND_ROUND:
        return SECOND_ROUND[kind](rng)
    raise ValueError(kind)


FLAG_VALUES = ["0", "-1", "1e-300", "1e300", "nan", "inf", "1e9", "abc", "", "1e-7", "0.5", "10"]


def _flag_case(rng: random.Random, out: str) -> Case:
    card = str(_card(rng))
    cmd = rng.choice(["simulate", "simulate", "estimate", "whatif", "measure", "design", "identify", "linearize",
                      "compare", "card", "calibrate"])
    v = rng.choice(FLAG_VALUES)
    files: dict[str, bytes] = {}
    env: dict[str, str] = {}
    if cmd == "simulate":
        flag = rng.choice(["--hours", "--particles", "--every", "--rpm", "--seed"])
        args = {"--hours": "0.2", "--particles": "200", "--every": "0.1"}
        args[flag] = v
        argv = ["simulate", card, *sum(([k, a] for k, a in args.items()), []), "--out", out, "--no-progress"]
    elif cmd == "estimate":
        flag = rng.choice(["--times", "--temperatures", "--particles", "--rpm", "--sigma-r", "--sigma-log-s"])
        files["a.csv"] = "\n".join(",".join(r) for r in base_table(rng, 59)).encode()
        files["b.csv"] = "\n".join(",".join(r) for r in base_table(rng, 59)).encode()
        args = {"--times": "0.2,0.4", "--particles": "200"}
        if flag in ("--times", "--temperatures"):
            v = rng.choice([f"{v},0.4", f"0.2,{v}", "1e9,25", "-300,25", "0.5,1e9", "25", "25,30,35"])
        args[flag] = v
        argv = ["estimate", card, "--samples", "@a.csv", "@b.csv", *sum(([k, a] for k, a in args.items()), []),
                "--out", out + "/e.csv"]
    elif cmd == "whatif":
        flag = rng.choice(["--seeds", "--particles", "--seed"])
        files["s.toml"] = _schedule_text(rng).encode()
        args = {"--seeds": "1", "--particles": "200"}
        args[flag] = v
        argv = ["whatif", card, "@s.toml", *sum(([k, a] for k, a in args.items()), []), "--out", out]
    elif cmd == "measure":
        flag = rng.choice(["--um-per-px", "--scale-bar-um", "--min-area-px", "--crop"])
        files["img.png"] = synthetic_micrograph(rng)
        if flag == "--crop":
            v = rng.choice(["0:10,0:10", "5:1,0:9", "0:1e9,0:5", "a:b", "0:96,0:96", "-5:3,0:9"])
        argv = ["measure", "@img.png", flag, v, "--out", out + "/m.csv"]
        if flag != "--um-per-px":
            argv += ["--um-per-px", "0.5"]
    elif cmd == "design":
        flag = rng.choice(["--hours", "--target"])
        if flag == "--target":
            v = rng.choice([f"s_mean_um={v}", f"r_mean={v}", "bogus=3", "s_mean_um", f"r_std={v}"])
        args = {"--hours": "1", "--target": "s_mean_um=30"}
        args[flag] = v
        argv = ["design", card, *sum(([k, a] for k, a in args.items()), []), "--out", out]
        env["BMCTL_BUDGET_CPU_H"] = "1e-9"
    elif cmd == "linearize":
        flag = rng.choice(["--rpm", "--at-hours", "--horizon"])
        v = rng.choice(FLAG_VALUES + ["2000", "1e6", "5e-324", "1001"])
        argv = ["linearize", card, flag, v, "--out", out]
    elif cmd == "compare":
        flag = rng.choice(["--at-h", "--particles", "--seed"])
        files["a.csv"] = _table_csv(rng)
        args = {"--at-h": "0.2", "--particles": "300"}
        args[flag] = rng.choice(FLAG_VALUES + ["1e9", "5000", "13"])
        v = args[flag]
        argv = ["compare", "@a.csv", "--model", card, *sum(([k, a] for k, a in args.items()), []), "--out", out]
    elif cmd == "card":
        flag = "--rpm"
        v = rng.choice([v, f"300,{v}", "1e20", "300,,400", ",", "-5", "2001"])
        argv = ["card", "show", card, "--rpm", v]
    elif cmd == "calibrate":
        flag = rng.choice(["--particles", "--replicates", "--seed", "--params", "--workers"])
        files.update(_history_files(rng))
        args = {"--particles": "100", "--workers": "0"}
        args[flag] = v if flag != "--params" else rng.choice(["bogus", "alpha,alpha", "", "mill.rpm_max", "gamma;x",
                                                                "card.name", "stochastic.alpha"])
        v = args[flag]
        argv = ["calibrate", card, "@h/h.toml", *sum(([k, a] for k, a in args.items()), []), "--out", out]
        env["BMCTL_BUDGET_CPU_H"] = "1e-9"
    else:
        flag = rng.choice(["--particles", "--random-schedules", "--seed"])
        args = {"--particles": "200", "--random-schedules": "0"}
        args[flag] = v
        argv = ["identify", card, "--quick", "--quiet", *sum(([k, a] for k, a in args.items()), []),
                "--out", "@c.moments.toml"]
        env["BMCTL_BUDGET_CPU_H"] = "1e-9"
    return Case("flags", f"{cmd} {flag} {v!r}", argv, files, [flag, "BMCTL_BUDGET", "a.csv", "b.csv", "img.png", "s.toml",
                                                          "--params", "h.toml"], env)


# --- fixtures: a campaign and an interrupted trial, built once per process and copied per case ----

_FIXTURES: dict[str, Path] = {}
CAMPAIGN_CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
CAMPAIGN_CTRL = {"recipe": ROOT / "controllers" / "recipe-300rpm-continuous.toml",
                 "lqr": ROOT / "controllers" / "lqr-baseline.toml"}
CAMPAIGN_HOURS = 2.0
RESUME_SCENARIO = f"""model = "{ROOT / 'models' / 'alni-1to1-300rpm-lab.toml'}"
hours = 1.5
[scenario]
name = "fuzz-resume"
description = "three 0.5 h steps, open loop"
[controller]
config = "{ROOT / 'controllers' / 'recipe-300rpm-continuous.toml'}"
[plant]
particles = 200
[sampling]
every_h = 0.5
particles = 40
[estimator]
particles = 60
"""


def _table_csv(rng: random.Random, n: int = 60) -> bytes:
    return ("\n".join(",".join(r) for r in base_table(rng, n)) + "\n").encode()


def fixtures() -> Path:
    """The folder of the shared fixtures (built on first call; removed when the process exits).

    ``campaign-fresh-<c>``: ``campaign init`` only; ``campaign-logged-<c>``: init, a 0.5 h log
    with a temperature reading, a sample at 0.5 h and an advice (``c``: recipe or lqr).
    ``trial-0``, ``trial-1``, ``trial-3``: the resume scenario stopped after 0 and 1 of its 3
    steps, and finished (same seed: ``trial-3/trajectory.csv`` is the reference of every resume).
    """
    if "root" in _FIXTURES:
        return _FIXTURES["root"]
    root = Path(tempfile.mkdtemp(prefix="bmctl-fuzz-fixtures-"))
    atexit.register(shutil.rmtree, root, True)
    from bmctl import campaign as cp
    from bmctl.trial import run_trial

    rng = random.Random("fixtures")
    (root / "t.csv").write_bytes(_table_csv(rng))
    for c, ctrl in CAMPAIGN_CTRL.items():
        fresh, logged = root / f"campaign-fresh-{c}", root / f"campaign-logged-{c}"
        cp.init(fresh, CAMPAIGN_CARD, ctrl, campaign_target(c), hours=CAMPAIGN_HOURS, particles=100)
        shutil.copytree(fresh, logged)
        cp.log(logged, 300.0, 0.5, 1.0, 40.0)
        cp.sample(logged, 0.5, [str(root / "t.csv")])
        cp.advise(logged)
    sc = root / "resume.toml"
    sc.write_text(RESUME_SCENARIO, encoding="utf-8")
    run_trial(sc, root / "trial-0", max_steps=0)
    shutil.copytree(root / "trial-0", root / "trial-1")
    run_trial(sc, root / "trial-1", resume=True, max_steps=1)
    shutil.copytree(root / "trial-1", root / "trial-3")
    run_trial(sc, root / "trial-3", resume=True)
    _FIXTURES["root"] = root
    return root


def _copy_fixture(name: str, dest: str = "out"):
    def setup(folder: Path) -> None:
        shutil.copytree(fixtures() / name, folder / dest)
    return setup


def _then(*steps):
    def setup(folder: Path) -> None:
        for st in steps:
            if st is not None:
                st(folder)
    return setup


# --- campaign cases ---------------------------------------------------------------------------------

CAMPAIGN_NUMBERS = ["0", "-1", "nan", "inf", "-inf", "1e300", "abc", "", "1e-300", "1e9"]


def _est_problems(name: str, est: dict, t_max_c: float) -> list[str]:
    bad = []
    for k, v in est.items():
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            continue
        if not math.isfinite(v):
            bad.append(f"{name}: {k} = {v}")
            continue
        base = k.removesuffix("_q05").removesuffix("_q95")
        if base in ("s_mean_um",) and not S_MIN_UM <= v <= S_MAX_UM:
            bad.append(f"{name}: {k} = {v:g} um outside [{S_MIN_UM:g}, {S_MAX_UM:g}]")
        elif base == "r_mean" and not 0.0 <= v < 1.0:
            bad.append(f"{name}: {k} = {v:g} outside [0, 1)")
        elif base in ("s_std_um", "r_std") and not v >= 0:
            bad.append(f"{name}: {k} = {v:g} < 0")
        elif base == "temperature_c" and not T_MIN_C <= v <= t_max_c:
            bad.append(f"{name}: {k} = {v:g} C outside [{T_MIN_C:g}, {t_max_c:g}]")
    return bad


def check_campaign(out: Path, t_max_c: float = AL_MELTING_C) -> list[str]:
    """Physical-bounds problems of an (undamaged) campaign database under ``out``: every stored
    estimate finite and physical, every logged and advised action finite with rpm >= 0 and the
    milling share in [0, 1], the log contiguous and within the batch."""
    path = out / "campaign.sqlite"
    if not path.is_file():
        return []
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        bad = []
        for t, e in con.execute("SELECT t_h, estimate FROM estimator_states"):
            bad += _est_problems(f"estimate at {t} h", json.loads(e), t_max_c)
        hours = json.loads(con.execute("SELECT value FROM meta WHERE key = 'hours'").fetchone()[0])
        if not (isinstance(hours, (int, float)) and 0 < hours <= 1000):
            bad.append(f"meta: hours = {hours}")
        end = 0.0
        for t0, t1, rpm, m in con.execute("SELECT t0_h, t1_h, rpm, milling FROM actions ORDER BY t0_h"):
            if not all(isinstance(v, float) and math.isfinite(v) for v in (t0, t1, rpm, m)):
                bad.append(f"action {t0}-{t1} h: {rpm} rpm, milling {m}")
            elif abs(t0 - end) > 1e-6 or t1 > hours + 1e-6 or rpm < 0 or not 0 <= m <= 1:
                bad.append(f"action {t0:g}-{t1:g} h: {rpm:g} rpm, milling {m:g} (log ends {end:g}, batch {hours:g} h)")
            else:
                end = t1
        for rpm, m, dt, adv in con.execute("SELECT rpm, milling, interval_h, advice FROM plans"):
            if not (math.isfinite(rpm) and rpm >= 0 and 0 <= m <= 1 and math.isfinite(dt) and dt > 0):
                bad.append(f"plan: {rpm} rpm, milling {m}, interval {dt} h")
            a = json.loads(adv)
            for k, e in (a.get("end") or {}).items():
                bad += _est_problems(f"advice end band {k}", {k: e["median"]}, t_max_c)
        return bad
    finally:
        con.close()


def _damage_db(rng: random.Random) -> tuple[Callable[[Path], None], str, list[str]]:
    """A damage to ``out/campaign.sqlite`` (the copied campaign): (setup step, label, names)."""
    op = rng.choice(["garbage", "truncate", "empty", "foreign", "version", "drop-table", "value", "value", "value",
                     "meta", "state", "input-changed", "input-missing", "db-is-folder", "no-db", "read-only",
                     "wal-blocked"])
    names = ["campaign.sqlite", "campaign database"]

    def db(folder: Path) -> Path:
        return folder / "out" / "campaign.sqlite"

    if op == "garbage":
        n = rng.choice([1, 100, 5000])
        data = bytes(rng.getrandbits(8) for _ in range(n))
        return (lambda f: db(f).write_bytes(data)), f"db garbage {n} B", names
    if op == "truncate":
        cut = rng.random()
        def step(f):
            raw = db(f).read_bytes()
            db(f).write_bytes(raw[: int(cut * len(raw))])
        return step, f"db truncated@{cut:.2f}", names
    if op == "empty":
        return (lambda f: db(f).write_bytes(b"")), "db empty", names
    if op == "foreign":
        tables = rng.choice([["CREATE TABLE foo (a)"], ["CREATE TABLE schema_version (version)",
                                                         "INSERT INTO schema_version VALUES (1)"],
                             ["CREATE TABLE schema_version (version)", "INSERT INTO schema_version VALUES ('one')"]])
        def step(f):
            db(f).unlink()
            con = sqlite3.connect(db(f))
            for q in tables:
                con.execute(q)
            con.commit()
            con.close()
        return step, f"db foreign schema ({len(tables)} statements)", names + ["schema"]
    if op == "version":
        v = rng.choice([2, 0, -1, "'1'", "X'01'", 1.5])
        return _sql(f"UPDATE schema_version SET version = {v}"), f"schema_version = {v}", names + ["schema"]
    if op == "drop-table":
        t = rng.choice(["meta", "actions", "samples", "particles", "estimator_states", "plans", "decisions",
                        "temperatures"])
        return _sql(f"DROP TABLE {t}"), f"drop {t}", names + [t]
    if op == "value":
        table, col = rng.choice([("actions", "rpm"), ("actions", "t1_h"), ("actions", "milling"), ("actions", "hours"),
                                 ("temperatures", "temperature_c"), ("samples", "t_h"), ("particles", "s_um"),
                                 ("particles", "r"), ("estimator_states", "estimate"), ("estimator_states", "t_h"),
                                 ("plans", "advice"), ("plans", "rpm"), ("plans", "t_h"), ("plans", "interval_h"),
                                 ("estimator_states", "state"), ("plans", "controller_state")])
        v = rng.choice(["'abc'", "X'00ff'", "1e308", "-1", "'nan'", "9e999", "-9e999", "''", "'{}'", "'[1]'"])
        return _sql(f"UPDATE {table} SET {col} = {v}"), f"{table}.{col} = {v}", names + [table, col]
    if op == "meta":
        key = rng.choice(["hours", "target", "seed", "particles", "inputs", "temperature_max_c"])
        v = rng.choice(["'abc'", "'-1'", "'1e300'", "'NaN'", "'null'", "'{}'", "'[1, 2]'", "X'00'", "'\"x\"'"])
        return (_sql(f"UPDATE meta SET value = {v} WHERE key = '{key}'"), f"meta.{key} = {v}",
                names + ["meta", key])
    if op == "state":
        blob = rng.choice(["X'00'", "X'504b0304'", "zeroblob(100)", "'abc'"])
        t = rng.choice(["estimator_states", "plans"])
        col = "state" if t == "estimator_states" else "controller_state"
        return _sql(f"UPDATE {t} SET {col} = {blob}"), f"{t}.{col} = {blob}", names + [t, col, "state"]
    if op == "input-changed":
        def step(f):
            p = next((f / "out" / "inputs").glob("controller-*.toml"))
            p.write_text(p.read_text(encoding="utf-8") + "\n# edited\n", encoding="utf-8")
        return step, "inputs/controller changed", ["inputs", "changed"]
    if op == "input-missing":
        return (lambda f: shutil.rmtree(f / "out" / "inputs")), "inputs/ removed", ["inputs", "changed or missing"]
    if op == "read-only":  # refuses writes unless the fuzz runs as root (then the command must simply work)
        def step(f):
            db(f).chmod(0o444)
            (f / "out").chmod(0o555)
        return step, "read-only folder and database", names + ["readonly", "read-only", "Permission denied"]
    if op == "wal-blocked":  # the write-ahead log cannot be created (a folder in its place): writes fail
        return (lambda f: (f / "out" / "campaign.sqlite-wal").mkdir()), "campaign.sqlite-wal is a folder", names
    if op == "db-is-folder":
        def step(f):
            db(f).unlink()
            db(f).mkdir()
        return step, "campaign.sqlite is a folder", names
    def step(f):
        db(f).unlink()
    return step, "campaign.sqlite removed", names + ["no campaign"]


def _sql(q: str) -> Callable[[Path], None]:
    def step(folder: Path) -> None:
        con = sqlite3.connect(folder / "out" / "campaign.sqlite")
        try:
            con.execute(q)
            con.commit()
        except sqlite3.DatabaseError:  # a constraint refused the damage: leave the file as it was
            pass
        finally:
            con.close()
    return step


def _verb_argv(rng: random.Random, verb: str, files: dict[str, bytes]) -> list[str]:
    if verb == "log":
        return ["campaign", "log", "@out", "--rpm", "300", "--hours", "0.5", "--temperature-c", "45"]
    if verb == "sample":
        files["s.csv"] = _table_csv(rng)
        return ["campaign", "sample", "@out", "--at-h", "0.5", "@s.csv"]
    if verb == "decide":
        return ["campaign", "decide", "@out", rng.choice(["--accept", "--reject"])]
    if verb == "report":
        return ["campaign", "report", "@out", "--out", "@out/report.html"]
    return ["campaign", verb, "@out"] + (["--json"] if verb in ("advise", "status") and rng.random() < 0.3 else [])


def campaign_target(ctrl: str) -> str:
    """The fixtures' campaign target: D50 45 µm, the mean size for the LQR (it tracks a moment)."""
    return "s_mean_um=45" if ctrl == "lqr" else "d50_um=45"


def _campaign_case(rng: random.Random) -> Case:
    op = rng.choice(["init", "init", "init-file", "log", "log", "log", "sample", "sample-table", "sample-image",
                     "decide", "damaged", "damaged", "damaged", "damaged"])
    ctrl = rng.choice(["recipe", "recipe", "lqr"])
    files: dict[str, bytes] = {}
    init = {"--model": str(CAMPAIGN_CARD), "--controller": str(CAMPAIGN_CTRL[ctrl]), "--target": campaign_target(ctrl),
            "--hours": "2", "--particles": "100"}
    verify = check_campaign
    then_advise = rng.random() < 0.4
    pre: list[list[str]] = []
    setup = None
    if op in ("init", "init-file"):
        if op == "init":
            flag = rng.choice(["--hours", "--hours", "--temperature-max-c", "--particles", "--seed", "--target",
                               "--target", "--model", "--controller", "DIR"])
            v = rng.choice(CAMPAIGN_NUMBERS)
            benign = {"--hours": ["0.5", "12", "24", "1000"], "--temperature-max-c": ["-50", "20", "60", "400"],
                      "--particles": ["50", "200"], "--seed": ["7", "123456789012"],
                      "--target": ["s_mean_um=40,r_mean=0.05", "r_std=0.01", "d90_um=80", "span=1.5", "d50_um=1e-3"]}
            if flag in benign and rng.random() < 0.35:  # a legitimate value: init (and advise) must then work
                v = rng.choice(benign[flag])
            elif flag == "--target":
                v = rng.choice([f"d50_um={v}", f"s_mean_um={v}", f"r_mean={v}", "bogus=3", "d50_um", "=",
                                "d50_um=45,s_mean_um=40", "d50_um=45,d50_um=46", "r_mean=2", "r_std=0.01,d50_um=45",
                                "s_std_um=1e-9", ",,", "D50_um=45"])
            elif flag == "--hours":
                v = rng.choice(CAMPAIGN_NUMBERS + ["1e6", "1000", "0.01", "24"])
            elif flag == "--temperature-max-c":
                v = rng.choice(CAMPAIGN_NUMBERS + ["-300", "5000", "20", "30"])
            elif flag in ("--model", "--controller"):
                v = rng.choice(["@missing.toml", "@", str(ROOT / "models"), str(ROOT / "README.md"),
                                str(CAMPAIGN_CTRL["lqr"]) if flag == "--model" else str(CAMPAIGN_CARD)])
            label = f"init {flag} {v!r}"
            if flag == "DIR":  # a folder that already holds a campaign, or is a file
                if rng.random() < 0.5:
                    setup = _copy_fixture(f"campaign-fresh-{ctrl}")
                    label = "init into an existing campaign"
                else:
                    files["out"] = b"not a folder"
                    label = "init DIR that is a file"
            else:
                init[flag] = v
            names = [flag, "target", "campaign.sqlite", "missing.toml", "models", "README.md", "toml",
                     "bmctl-fuzz-"]  # '@' is the case's own folder
        else:
            which = rng.choice(["card", "controller"])
            src = CAMPAIGN_CARD if which == "card" else CAMPAIGN_CTRL[ctrl]
            data, names, label = mutate_toml(rng, src.read_text(encoding="utf-8"))
            files["x.toml"] = data
            init["--model" if which == "card" else "--controller"] = "@x.toml"
            names = names + ["x.toml"]
            label = f"init {which}: {label}"
        argv = ["campaign", "init", "@out", *sum(([k, a] for k, a in init.items()), [])]
        if then_advise:
            pre, argv = [argv], ["campaign", "advise", "@out"]
            label += " + advise"
        return Case("campaign", label, argv, files, names, pre=pre, setup=setup, verify=verify,
                    env={"BMCTL_BUDGET_CPU_H": "0.01"})
    base = rng.choice(["logged", "logged", "fresh"])
    setup_steps = [_copy_fixture(f"campaign-{base}-{ctrl}")]
    if op == "log":
        flag = rng.choice(["--rpm", "--rpm", "--hours", "--hours", "--milling", "--temperature-c", "--from-h",
                           "--from-h"])
        args = {"--rpm": "300", "--hours": "0.5", "--milling": "0.75", "--temperature-c": "45"}
        pool = {"--rpm": CAMPAIGN_NUMBERS + ["5000", "100", "499"],
                "--hours": CAMPAIGN_NUMBERS + ["1.5", "1.6", "2", "1e-9", "0.001"],
                "--milling": CAMPAIGN_NUMBERS + ["1.5", "-0.1", "0.5", "1"],
                "--temperature-c": CAMPAIGN_NUMBERS + ["-300", "5000", "399", "25", "-50"],
                "--from-h": CAMPAIGN_NUMBERS + ["0.2", "0.5", "0.4999999", "0.5000001", "5", "2"]}[flag]
        args[flag] = rng.choice(pool)
        argv = ["campaign", "log", "@out", *sum(([k, a] for k, a in args.items()), [])]
        label = f"log {flag} {args[flag]!r} on {base}-{ctrl}"
        names = [flag, "--hours", "--from-h"]
    elif op in ("sample", "sample-table", "sample-image"):
        at = "0.5"
        if op == "sample":
            at = rng.choice(CAMPAIGN_NUMBERS + ["0.25", "0.5", "1.9", "2.0", "2.1", "100", "-0.0"])
            files["s.csv"] = _table_csv(rng)
            inputs = ["@s.csv"]
            label = f"sample --at-h {at!r} on {base}-{ctrl}"
            names = ["--at-h"]
        elif op == "sample-table":
            data, names, label = mutate_table(rng)
            files["s.csv"] = data
            inputs = ["@s.csv"]
            label = f"sample table: {label}"
            names = names + ["s.csv"]
        else:
            data, suffix, label = mutate_image(rng)
            files[f"img{suffix}"] = data
            flags = rng.choice([["--um-per-px", "0.5"], ["--um-per-px", "nan"], ["--um-per-px", "1e-300"], []])
            inputs = [f"@img{suffix}", *flags]
            label = f"sample image: {label} {' '.join(flags)}"
            names = ["img" + suffix, "--um-per-px", "--scale-bar-um"]
        argv = ["campaign", "sample", "@out", "--at-h", at, *inputs]
    elif op == "decide":
        choice = rng.choice(["accept", "reject-rpm", "reject-milling", "accept-rpm", "after-log", "note"])
        argv = ["campaign", "decide", "@out"]
        if choice == "accept":
            argv.append("--accept")
        elif choice == "reject-rpm":
            argv += ["--reject", "--rpm", rng.choice(CAMPAIGN_NUMBERS + ["5000"])]
        elif choice == "reject-milling":
            argv += ["--reject", "--milling", rng.choice(CAMPAIGN_NUMBERS + ["1.5"])]
        elif choice == "accept-rpm":
            argv += ["--accept", "--rpm", "200"]
        elif choice == "after-log":
            pre = [["campaign", "log", "@out", "--rpm", "300", "--hours", "0.5"]]
            argv.append("--accept")
        else:
            argv += ["--accept", "--note", rng.choice(["\u00e9\u2603\U0001f600", "x" * 100_000, "'; DROP TABLE plans; --",
                                                       "\x00\x01"])]
        label = f"decide {choice} on {base}-{ctrl}: {' '.join(argv[3:])[:40]}"
        names = ["--rpm", "--milling", "--accept", "--reject", "advice"]
    else:
        step, label, names = _damage_db(rng)
        setup_steps.append(step)
        verb = rng.choice(["advise", "advise", "status", "status", "log", "sample", "decide", "report"])
        argv = _verb_argv(rng, verb, files)
        label = f"{label} on {base}-{ctrl}: {verb}"
        names = names + (["advice"] if verb == "decide" else [])
        verify = None  # the damage is in the checked database; stdout is checked
    if then_advise and op != "damaged" and not pre:
        pre, argv = [argv], ["campaign", "advise", "@out"]
        label += " + advise"
    return Case("campaign", label, argv, files, names, pre=pre, setup=_then(*setup_steps), verify=verify,
                env={"BMCTL_BUDGET_CPU_H": "0.01"})


# --- resume cases -------------------------------------------------------------------------------------

def reference_rows() -> list[list[str]]:
    """The finished trial's ``trajectory.csv`` rows (header first)."""
    with open(fixtures() / "trial-3" / "trajectory.csv", newline="", encoding="utf-8") as fh:
        return list(csv.reader(fh))


def check_resumed(exact: bool) -> Callable[[Path], list[str]]:
    """A verify: the resumed trial finished all 3 steps, and (``exact``) its trajectory is the
    uninterrupted run's (the solve-time column aside)."""
    def verify(out: Path) -> list[str]:
        bad = check_outputs(out)
        traj, summ = out / "trajectory.csv", out / "summary.json"
        if not summ.is_file():
            return bad + ["summary.json missing after exit 0"]
        try:
            steps = json.loads(summ.read_text(encoding="utf-8"))["steps"]
        except (ValueError, KeyError, TypeError):
            return bad + ["summary.json unreadable after exit 0"]
        with open(traj, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
        ref = reference_rows()
        if steps != 3 or len(rows) != len(ref):
            return bad + [f"{steps} steps, {len(rows) - 1} rows (the trial has 3)"]
        if exact:
            skip = ref[0].index("solve_ms")
            for i, (a, b) in enumerate(zip(rows, ref)):
                if [x for j, x in enumerate(a) if j != skip] != [x for j, x in enumerate(b) if j != skip]:
                    return bad + [f"trajectory.csv row {i + 1} differs from the uninterrupted run"]
        return bad
    return verify


def _resume_case(rng: random.Random) -> Case:
    base = rng.choice(["trial-0", "trial-1", "trial-1", "trial-3"])
    k = int(base[-1])
    ref = reference_rows()
    line = lambda row: ",".join(row) + "\n"  # noqa: E731
    target = rng.choice(["trajectory", "trajectory", "checkpoint", "checkpoint", "checkpoint", "meta", "none",
                         "flags"])
    exact = True
    argv_extra: list[str] = []
    names: list[str] = []

    def out(folder: Path, name: str) -> Path:
        return folder / "out" / name

    def write(name: str, data: bytes):
        return lambda f: out(f, name).write_bytes(data)

    step: Callable[[Path], None] | None = None
    if target == "trajectory":
        names = ["trajectory.csv"]
        op = rng.choice(["torn", "torn", "extra-row", "empty", "missing", "header-only", "garbage", "value",
                         "short-row", "long-row", "header", "crlf", "no-newline-at-all"])
        label = f"trajectory.csv {op}"
        if op == "torn" and k < 3:
            cut = rng.randrange(1, len(line(ref[k + 1])) - 1)
            step = lambda f: out(f, "trajectory.csv").open("a", encoding="utf-8").write(line(ref[k + 1])[:cut])  # noqa: E731
            label += f"@{cut}"
        elif op == "extra-row" and k < 3:
            step = lambda f: out(f, "trajectory.csv").open("a", encoding="utf-8").write(line(ref[k + 1]))  # noqa: E731
        elif op == "empty":
            step = write("trajectory.csv", b"")
        elif op == "missing":
            step = lambda f: out(f, "trajectory.csv").unlink()  # noqa: E731
        elif op == "header-only":
            step = write("trajectory.csv", line(ref[0]).encode())
        elif op == "garbage":
            step = write("trajectory.csv", bytes(rng.getrandbits(8) for _ in range(rng.choice([10, 3000]))))
        elif op in ("value", "short-row", "long-row") and k >= 1:
            i = rng.randrange(1, k + 1)
            rows = [list(r) for r in ref[: k + 1]]
            if op == "value":
                j = rng.randrange(len(rows[i]))
                rows[i][j] = rng.choice(["abc", "nan", "", "1e999", "-1", "\x00"])
                label += f" row {i} {ref[0][j]}={rows[i][j]!r}"
            elif op == "short-row":
                rows[i] = rows[i][:-3]
            else:
                rows[i] = rows[i] + ["7"]
            step = write("trajectory.csv", "".join(line(r) for r in rows).encode())
        elif op == "header":
            rows = [list(r) for r in ref[: k + 1]]
            rows[0] = rows[0][::-1]
            step = write("trajectory.csv", "".join(line(r) for r in rows).encode())
        elif op == "crlf":
            step = write("trajectory.csv", "".join(",".join(r) + "\r\n" for r in ref[: k + 1]).encode())
        else:
            step = write("trajectory.csv", ",".join(ref[0]).encode())
            label = "trajectory.csv: the header without its newline"
        exact = op in ("torn", "extra-row", "crlf")
    elif target == "checkpoint":
        names = ["checkpoint.npz", "checkpoint"]
        op = rng.choice(["truncated", "garbage", "empty", "missing", "foreign", "object", "json-garbage",
                         "json-list", "other-step", "leaf", "leaf", "pickle", "pkl-beside", "folder", "npy-bomb",
                         "npy-bomb"])
        label = f"checkpoint.npz {op}"
        if op == "truncated":
            cut = rng.random()
            def step(f):
                raw = out(f, "checkpoint.npz").read_bytes()
                out(f, "checkpoint.npz").write_bytes(raw[: int(cut * len(raw))])
            label += f"@{cut:.2f}"
        elif op == "garbage":
            step = write("checkpoint.npz", bytes(rng.getrandbits(8) for _ in range(rng.choice([10, 5000]))))
        elif op == "empty":
            step = write("checkpoint.npz", b"")
        elif op == "missing":
            step = lambda f: out(f, "checkpoint.npz").unlink()  # noqa: E731
        elif op == "folder":
            def step(f):
                out(f, "checkpoint.npz").unlink()
                out(f, "checkpoint.npz").mkdir()
        elif op in ("foreign", "object", "json-garbage", "json-list"):
            def step(f, op=op):
                with open(out(f, "checkpoint.npz"), "wb") as fh:
                    if op == "foreign":
                        np.savez(fh, a=np.arange(3.0), b=np.zeros((2, 2)))
                    elif op == "object":
                        np.savez(fh, __json__=np.array(['{"loop": {"__array__": "/x"}}']),
                                 **{"/x": np.array([{"a": 1}, None], dtype=object)})
                    elif op == "json-garbage":
                        np.savez(fh, __json__=np.array("{not json"))
                    else:
                        np.savez(fh, __json__=np.array("[1, 2]"))
        elif op == "other-step":
            other = rng.choice([b for b in ("trial-0", "trial-1", "trial-3") if b != base])
            step = lambda f: shutil.copyfile(fixtures() / other / "checkpoint.npz", out(f, "checkpoint.npz"))  # noqa: E731
            label += f" (of {other})"
            exact = True
        elif op == "leaf":
            from bmctl.checkpoint import load_state, save_state

            state = load_state(fixtures() / base / "checkpoint.npz")
            leaves = [(p, v) for p, v in _state_leaves(state)]
            path, v = rng.choice(leaves)
            nv = _swap_leaf(rng, v) if not isinstance(v, np.ndarray) else _swap_array(rng, v)
            _set(state, path, nv)
            label += f" {'/'.join(map(str, path))}={str(nv)[:20]}"
            step = lambda f: save_state(out(f, "checkpoint.npz"), state)  # noqa: E731
            names += [str(x) for x in path]
            exact = False
        elif op == "npy-bomb":  # an array header declaring far more than the file holds
            shape = rng.choice([(10**12,), (10**6, 10**6), (2**62,), (1000,), (-1,)])
            dtype = rng.choice(["<f8", "|O", "<U100000000", "<c16"])
            members = {"plant/s.npy": npy_bomb(shape, dtype)}
            if rng.random() < 0.5:
                members["__json__.npy"] = npy_bomb((), "<U10", b"x" * 40)
            step = write("checkpoint.npz", npz_with(members))
            label += f" {shape} {dtype}"
        elif op == "pickle":
            import pickle

            step = write("checkpoint.npz", pickle.dumps({"loop": {"k": 1}}))
        else:  # a pickle beside the checkpoint must be ignored
            import pickle

            step = write("checkpoint.pkl", pickle.dumps({"loop": {"k": 99}}))
        exact = exact if op in ("other-step", "leaf") else True
    elif target == "meta":
        names = ["trial.json", "--resume"]
        op = rng.choice(["garbage", "empty", "missing", "list", "types", "seed", "scenario", "null", "extra"])
        label = f"trial.json {op}"
        meta = json.loads((fixtures() / base / "trial.json").read_text(encoding="utf-8"))
        data = {"garbage": b"\xff\xfe{{", "empty": b"", "list": b"[1, 2]", "null": b"null",
                "types": json.dumps({"scenario": 5, "seed": "0"}).encode(),
                "seed": json.dumps({**meta, "seed": 1}).encode(),
                "scenario": json.dumps({**meta, "scenario": "/elsewhere/sc.toml"}).encode(),
                "extra": json.dumps({**meta, "x": [1, 2]}).encode()}.get(op)
        step = (lambda f: out(f, "trial.json").unlink()) if op == "missing" else write("trial.json", data)  # noqa: E731
    elif target == "flags":
        v = rng.choice(["1", "-1", "abc", "1e300"])
        argv_extra = ["--seed", v]
        label = f"--seed {v!r} differs from the trial's"
        names = ["--seed", "--resume", "trial.json"]
    else:
        label = "no damage"
        if k == 3 and rng.random() < 0.5:
            step = write("summary.json", b"\x00garbage")
            label = "summary.json garbage"
    argv = ["trial", str(fixtures() / "resume.toml"), "--resume", "@out", "--no-progress", *argv_extra]
    return Case("resume", f"{base}: {label}", argv, {}, names + ["trajectory.csv", "checkpoint.npz", "trial.json"],
                setup=_then(_copy_fixture(base), step), verify=check_resumed(exact))


def _state_leaves(data, prefix=()):
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _state_leaves(v, prefix + (k,))
    elif isinstance(data, list) and data:
        for i, v in enumerate(data):
            yield from _state_leaves(v, prefix + (i,))
    else:
        yield prefix, data


def _swap_leaf(rng: random.Random, v):
    """A value of another type, or a non-finite number (damage a checkpoint's structure can show;
    a value of the right type changed to another is an edit no check of the form can see)."""
    return rng.choice(["abc", "", True, [v, v], {"x": 1}, float("nan"), float("inf"), 2**70 * 1.0 if isinstance(v, int)
                       and not isinstance(v, bool) else "1"])


def _swap_array(rng: random.Random, a: np.ndarray):
    op = rng.choice(["nan", "shape", "empty", "dtype", "scalar"])
    if op == "nan":
        b = np.array(a, dtype=float, copy=True)
        if b.size:
            b.flat[rng.randrange(b.size)] = np.nan
        return b
    if op == "shape":
        return np.resize(a, (a.size + 3,))
    if op == "empty":
        return a[:0]
    if op == "dtype":
        return np.asarray(a).astype("U8")
    return 1.0



# --- second-round kinds: nesting, special files, histories, unbounded work, one-line errors, crafted
# --- databases -------------------------------------------------------------------------------------------

LAB_CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE_CTRL = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
#: what a refusal of unbounded work names
BUDGET_NAMES = ["over the budget", "must be", "BMCTL_BUDGET"]


def _mkfifo(path: Path) -> None:
    import os

    if path.exists() or path.is_symlink():
        path.unlink() if not path.is_dir() else shutil.rmtree(path)
    os.mkfifo(path)


def special_file(kind: str) -> Callable[[Path], None]:
    """A setup step turning a path (relative to the case folder) into a FIFO, a link to a device,
    a folder, or a link leading out of the folder."""
    def make(path: Path) -> None:
        if path.exists() or path.is_symlink():
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
        if kind == "fifo":
            _mkfifo(path)
        elif kind in ("/dev/zero", "/dev/urandom", "/dev/null"):
            path.symlink_to(kind)
        elif kind == "folder":
            path.mkdir()
        elif kind == "dangling":
            path.symlink_to(path.parent / "nowhere" / "x")
        else:
            raise ValueError(kind)
    return make


SPECIAL_KINDS = ("fifo", "fifo", "/dev/zero", "/dev/urandom", "/dev/null", "folder", "dangling")


def _nesting_case(rng: random.Random) -> Case:
    """A TOML value or JSON document nested deeper than bmctl reads, in any file a command reads."""
    depth = rng.choice([65, 1000, 100_000])
    target = rng.choice(["card", "schedule", "scenario", "controller", "history", "trial.json", "checkpoint",
                         "advice", "estimate", "meta"])
    deep_t = deep_toml_value(depth) if rng.random() < 0.6 else "{a = " * depth + "1" + "}" * depth
    deep_j = deep_json(depth) if rng.random() < 0.6 else '{"a": ' * depth + "1" + "}" * depth
    label = f"{target} nested {depth} deep"
    if rng.random() < 0.25:  # quotes and escapes that a backtracking scanner takes quadratic time over
        deep_t = rng.choice(['"' + '\\"' * 200_000, '"""' + "a" * 300_000 + "\\", ('"' + '\\"' * 5 + "\n") * 50_000,
                             "'''" + "[" * 300_000])
        deep_j = rng.choice(['"' + '\\"' * 200_000, '["' + '\\"' * 200_000, '"' * 500_000])
        label = f"{target}: {len(deep_t)} characters of unclosed quotes and escapes"
    names = ["nested", "not a bmctl", "damaged", "malformed", "not JSON", "Expected", "Invalid", "unterminated",
             "Unterminated", "Illegal"]
    files: dict[str, bytes] = {}
    env = {"BMCTL_BUDGET_CPU_H": "0.01"}
    if target == "card":
        files["card.toml"] = (f"zz = {deep_t}\n" + LAB_CARD.read_text(encoding="utf-8")).encode()
        argv = rng.choice([["card", "show", "@card.toml"], ["simulate", "@card.toml", "--hours", "0.1", "--out", "@out"],
                           ["linearize", "@card.toml", "--out", "@out"]])
        return Case("nesting", label, argv, files, names + ["card.toml"], env)
    if target == "schedule":
        files["s.toml"] = f"zz = {deep_t}\n{_schedule_text(rng)}".encode()
        return Case("nesting", label, ["whatif", str(LAB_CARD), "@s.toml", "--seeds", "1", "--particles", "200",
                                       "--out", "@out"], files, names + ["s.toml"], env)
    if target == "scenario":
        files["sc.toml"] = SCENARIO_BASE.format(model=LAB_CARD, controller=RECIPE_CTRL).replace(
            "hours = 0.5", f"hours = 0.5\nzz = {deep_t}").encode()
        return Case("nesting", label, ["trial", "@sc.toml", "--out", "@out", "--no-progress"], files,
                    names + ["sc.toml"], env)
    if target == "controller":
        files["c.toml"] = (f"zz = {deep_t}\n" + RECIPE_CTRL.read_text(encoding="utf-8")).encode()
        return Case("nesting", label, ["design", str(LAB_CARD), "--target", "s_mean_um=30", "--hours", "1",
                                       "--controller", "@c.toml", "--out", "@out"], files, names + ["c.toml"],
                    {"BMCTL_BUDGET_CPU_H": "1e-9"})
    if target == "history":
        files.update(_history_files(rng, extra=f"zz = {deep_t}\n"))
        return Case("nesting", label, _calibrate_argv(), files, names + ["h.toml"], {"BMCTL_BUDGET_CPU_H": "1e-9"})
    if target in ("trial.json", "checkpoint"):
        base = rng.choice(["trial-1", "trial-3"])
        if target == "trial.json":
            step = lambda f: (f / "out" / "trial.json").write_text(deep_j, encoding="utf-8")  # noqa: E731
        else:
            def step(f):
                from bmctl.checkpoint import JSON_KEY

                with np.load(f / "out" / "checkpoint.npz", allow_pickle=False) as z:
                    arrays = {k: z[k] for k in z.files}
                arrays[JSON_KEY] = np.array(deep_j)
                with open(f / "out" / "checkpoint.npz", "wb") as fh:
                    np.savez(fh, **arrays)
        return Case("nesting", f"{base}: {label}", _resume_argv(), {}, names + [target],
                    setup=_then(_copy_fixture(base), step))
    col = {"advice": ("plans", "advice"), "estimate": ("estimator_states", "estimate"), "meta": ("meta", "value")}[target]
    q = f"UPDATE {col[0]} SET {col[1]} = ?" + (f" WHERE key = '{rng.choice(['target', 'inputs', 'hours'])}'"
                                                if target == "meta" else "")
    verb = rng.choice(["status", "advise", "decide", "report", "log"])
    return Case("nesting", f"campaign {label}: {verb}", _verb_argv(rng, verb, files), files,
                names + ["campaign.sqlite", col[0]], env,
                setup=_then(_copy_fixture(f"campaign-logged-{rng.choice(['recipe', 'lqr'])}"), _sql_args(q, deep_j)))


def _sql_args(q: str, *args) -> Callable[[Path], None]:
    def step(folder: Path) -> None:
        con = sqlite3.connect(folder / "out" / "campaign.sqlite")
        try:
            con.execute(q, args)
            con.commit()
        finally:
            con.close()
    return step


def _resume_argv() -> list[str]:
    return ["trial", str(fixtures() / "resume.toml"), "--resume", "@out", "--no-progress"]


def _special_case(rng: random.Random) -> Case:
    """An input that is a FIFO, a link to a device, a folder or a dangling link, wherever a command reads."""
    kind = rng.choice(SPECIAL_KINDS)
    where = rng.choice(["card", "schedule", "table", "image", "scenario", "controller", "history-table",
                        "trial.json", "checkpoint.npz", "trajectory.csv", "campaign-input", "campaign-sample"])
    label = f"{where} is {kind}"
    names = ["not a regular file", "is a directory", "not found", "no such file", "cannot read", "changed or missing",
             "missing"]
    files: dict[str, bytes] = {}
    env = {"BMCTL_BUDGET_CPU_H": "0.01"}
    if where in ("trial.json", "checkpoint.npz", "trajectory.csv"):
        base = rng.choice(["trial-1", "trial-3"])
        return Case("special", f"{base}: {label}", _resume_argv(), {}, names + [where],
                    setup=_then(_copy_fixture(base), lambda f: special_file(kind)(f / "out" / where)))
    if where == "campaign-input":
        def step(f):
            special_file(kind)(next((f / "out" / "inputs").glob("*.toml")))
        verb = rng.choice(["status", "advise", "decide", "report"])
        return Case("special", f"{label}: {verb}", _verb_argv(rng, verb, files), files,
                    names + ["inputs", "campaign.sqlite"], env,
                    setup=_then(_copy_fixture(f"campaign-logged-{rng.choice(['recipe', 'lqr'])}"), step))
    if where == "campaign-sample":
        return Case("special", label, ["campaign", "sample", "@out", "--at-h", "0.5", "@x.csv"], {},
                    names + ["x.csv"], env, setup=_then(_copy_fixture("campaign-logged-recipe"),
                                                       lambda f: special_file(kind)(f / "x.csv")))
    if where == "history-table":
        files.update(_history_files(rng))
        return Case("special", label, _calibrate_argv(), files, names + ["t0.csv", "h.toml"],
                    {"BMCTL_BUDGET_CPU_H": "1e-9"}, setup=lambda f: special_file(kind)(f / "h" / "t0.csv"))
    name, argv = {
        "card": ("x.toml", rng.choice([["card", "show", "@x.toml"], ["simulate", "@x.toml", "--out", "@out"],
                                       ["linearize", "@x.toml", "--out", "@out"]])),
        "schedule": ("x.toml", ["whatif", str(LAB_CARD), "@x.toml", "--seeds", "1", "--out", "@out"]),
        "table": ("x.csv", rng.choice([["measure", "@x.csv", "--out", "@out/m.csv"],
                                       ["estimate", str(LAB_CARD), "--samples", "@x.csv", "--times", "0.5",
                                        "--out", "@out/e.csv"],
                                       ["compare", "@x.csv", "--model", str(LAB_CARD), "--at-h", "0.5",
                                        "--out", "@out"]])),
        "image": ("x.png", ["measure", "@x.png", "--um-per-px", "0.5", "--out", "@out/m.csv"]),
        "scenario": ("x.toml", ["trial", "@x.toml", "--out", "@out", "--no-progress"]),
        "controller": ("x.toml", ["design", str(LAB_CARD), "--target", "s_mean_um=30", "--controller", "@x.toml",
                                  "--out", "@out"]),
    }[where]
    return Case("special", label, argv, {}, names + [name], env, setup=lambda f: special_file(kind)(f / name))


# --- calibrate histories -----------------------------------------------------------------------------------

def _history_files(rng: random.Random, name: str = "run", tables: tuple[str, str] = ("t0.csv", "t1.csv"),
                   extra: str = "", schedule: str | None = None) -> dict[str, bytes]:
    """A history of two samples (tables in the case folder) and its tables."""
    sched = (f"schedule = {json.dumps(schedule)}\n" if schedule is not None else "")
    body = (f"name = {json.dumps(name)}\n{sched}{extra}"
            + ("" if schedule is not None else "[[segment]]\nhours = 1.0\nrpm = 300\n")
            + "".join(f"[[sample]]\nt_h = {t}\ntable = {json.dumps(tab)}\n" for t, tab in zip((0.5, 1.0), tables)))
    return {"h/h.toml": body.encode(), "h/t0.csv": _table_csv(rng), "h/t1.csv": _table_csv(rng)}


def _calibrate_argv(*extra: str) -> list[str]:
    return ["calibrate", str(LAB_CARD), "@h/h.toml", "--params", "gamma", "--particles", "100", "--workers", "0",
            "--out", "@out", *extra]


SECRET = "BMCTL-SENTINEL-NEVER-READ"


def _history_case(rng: random.Random) -> Case:
    """A hostile calibrate history: mutated, a name that is a path, a table or schedule outside its folder."""
    op = rng.choice(["mutate", "mutate", "name", "name", "table", "table", "schedule", "link-out", "run"])
    files = _history_files(rng)
    env = {"BMCTL_BUDGET_CPU_H": "1e-9"}  # the fit itself is refused by the work check unless the input is bad first
    names = ["h.toml", "over the budget"]
    setup = None
    if op == "mutate":
        data, n, label = mutate_toml(rng, files["h/h.toml"].decode())
        files["h/h.toml"] = data
        names += n
    elif op in ("name", "run"):
        name = rng.choice(["../../../X", "../X", "/tmp/X", "a/b", "..", ".", "", "x" * 300, "-rf", "con",
                           "~/.bashrc", "run"])
        files = _history_files(rng, name=name)
        label = f"name = {name[:20]!r}"
        if op == "run" or rng.random() < 0.3:  # run the fit to its end: figures must land inside --out
            env = {"BMCTL_BUDGET_CPU_H": "0.05"}
            label += " (run)"
        names += ["name"]
    elif op == "table":  # the history's folder is h/; secret.csv lies beside it, in the case folder
        ref = rng.choice(["/etc/passwd", "../secret.csv", "../../../../../../../../etc/passwd", "@abs",
                          "t0.csv/../../secret.csv", "sub/../../secret.csv", "", ".", "/dev/zero"])
        label = f"table = {ref!r}"

        def setup(f, ref=ref):
            (f / "secret.csv").write_text(f"{SECRET},r\n40,0.05\n" * 20, encoding="utf-8")
            r = str(f / "secret.csv") if ref == "@abs" else ref
            (f / "h" / "h.toml").write_text((f / "h" / "h.toml").read_text(encoding="utf-8").replace('"t0.csv"', json.dumps(r), 1), encoding="utf-8")
        names += ["sample[0].table", "sample[0]"]
    elif op == "schedule":
        ref = rng.choice(["/etc/passwd", "../s.toml", "@abs"])
        files = _history_files(rng, schedule="PLACEHOLDER")
        label = f"schedule = {ref!r}"

        def setup(f, ref=ref):
            (f / "s.toml").write_text(f"name = \"{SECRET}\"\n[[segment]]\nhours = 1.0\nrpm = 300\n", encoding="utf-8")
            r = str(f / "s.toml") if ref == "@abs" else ref
            (f / "h" / "h.toml").write_text((f / "h" / "h.toml").read_text(encoding="utf-8").replace('"PLACEHOLDER"', json.dumps(r)), encoding="utf-8")
        names += ["schedule"]
    else:  # a table that is a link leading out of the history's folder
        label = "t0.csv links outside"

        def setup(f):
            (f / "secret.csv").write_text(f"{SECRET},r\n40,0.05\n" * 20, encoding="utf-8")
            (f / "h" / "t0.csv").unlink()
            (f / "h" / "t0.csv").symlink_to(f / "secret.csv")
        names += ["sample[0].table", "leads outside"]
    return Case("history", f"history: {label}", _calibrate_argv(), files, names, env, setup=setup, sentinel=SECRET)


# --- unbounded work under the default budget ------------------------------------------------------------------

def _work_case(rng: random.Random) -> Case:
    """A command asked for far more than an interactive run (refused under the default budget before
    it starts), or for a modest run under a budget of 18 CPU seconds (it runs, or is refused naming
    the flags): never a run past the time limit."""
    files = {"a.csv": _table_csv(rng), "b.csv": _table_csv(rng), "s.toml": _schedule_text(rng).encode()}
    files.update(_history_files(rng))
    huge = rng.random() < 0.5
    card = str(rng.choice(CARDS))
    pick = rng.choice
    choices = [  # (far beyond the default budget, modest)
        (["simulate", card, "--particles", "10000000", "--out", "@out", "--no-progress"],
         ["simulate", card, "--hours", pick(["0.05", "0.5", "12"]), "--particles", pick(["500", "20000", "200000"]),
          "--out", "@out", "--no-progress"]),
        (["simulate", card, "--hours", "1000", "--particles", pick(["1000000", "100000"]), "--out", "@out", "--no-progress"],
         ["simulate", card, "--hours", pick(["0.1", "1000"]), "--every", pick(["0.01", "0.001"]), "--particles", "200",
          "--out", "@out", "--no-progress"]),
        (["compare", "@a.csv", "--model", card, "--at-h", "12", "--particles", pick(["10000000", "1000000000"]),
          "--out", "@out"],
         ["compare", "@a.csv", "--model", card, "--at-h", pick(["0.2", "12"]), "--particles", pick(["500", "200000"]),
          "--out", "@out"]),
        (["estimate", card, "--samples", "@a.csv", "@b.csv", "--times", pick(["0.5,1000", "1,900"]),
          "--particles", pick(["1000000", "100000"]), "--out", "@out/e.csv"],
         ["estimate", card, "--samples", "@a.csv", "@b.csv", "--times", pick(["0.5,1", "40,659", "10,100"]),
          "--particles", pick(["100", "200", "20000"]), "--out", "@out/e.csv"]),
        (["linearize", card, "--at-hours", pick(["1e6", "2000", "1e300"]), "--out", "@out"],
         ["linearize", card, "--at-hours", pick(["0", "1000", "12"]), "--horizon", pick(["2", "1000"]), "--out", "@out"]),
        (["whatif", card, "@s.toml", "--seeds", "1000", "--particles", "1000000", "--out", "@out"],
         ["whatif", card, "@s.toml", "--seeds", pick(["1", "100"]), "--particles", pick(["200", "100000"]),
          "--workers", "0", "--out", "@out"]),
        (["identify", card, "--particles", "1000000", "--random-schedules", "200", "--out", "@c.moments.toml"],
         ["identify", card, "--quick", "--quiet", "--particles", pick(["200", "1000000"]), "--out", "@c.moments.toml"]),
        (_calibrate_argv("--particles", "1000000", "--replicates", "64"),
         _calibrate_argv("--replicates", pick(["2", "64"]), "--particles", pick(["100", "100000"]))),
        (["design", card, "--target", "s_mean_um=30", "--hours", "1000", "--out", "@out"],
         ["design", card, "--target", "s_mean_um=30", "--hours", pick(["1", "1000"]), "--out", "@out"]),
    ]
    argv = rng.choice(choices)[0 if huge else 1]
    env = {} if huge else {"BMCTL_BUDGET_CPU_H": "0.005"}
    words = [a for a in argv[:1] + argv[2:] if not a.startswith("@")]
    return Case("work", f"{'default budget' if huge else '18 CPU s'}: {' '.join(words)[:90]}", argv, files,
                BUDGET_NAMES + ["--at-hours", "--particles", "--times"], env)


# --- one line, whatever an error quotes ------------------------------------------------------------------------

def _names_case(rng: random.Random) -> Case:
    """A flag or value holding newlines, control characters or 200,000 characters, on any command."""
    v = rng.choice(["a\nb", "x" * 200_000, "\r\n", "\x1b[2J", "\u2028", "\x00", "1e9\n", "é\u0301\u200b",
                    "--out\nbmctl: error: fake"])
    cmd = rng.choice(["simulate", "estimate", "whatif", "measure", "design", "linearize", "compare", "card",
                      "campaign", "trial", "calibrate", "unknown-flag", "unknown-command"])
    files = {"a.csv": _table_csv(rng), "s.toml": _schedule_text(rng).encode(), "img.png": synthetic_micrograph(rng)}
    argv = {
        "simulate": ["simulate", str(LAB_CARD), "--hours", v, "--out", "@out"],
        "estimate": ["estimate", str(LAB_CARD), "--samples", "@a.csv", "--times", v, "--out", "@out/e.csv"],
        "whatif": ["whatif", str(LAB_CARD), "@s.toml", "--seeds", v, "--out", "@out"],
        "measure": ["measure", "@img.png", "--crop", v, "--um-per-px", "0.5", "--out", "@out/m.csv"],
        "design": ["design", str(LAB_CARD), "--target", v, "--out", "@out"],
        "linearize": ["linearize", str(LAB_CARD), "--rpm", v, "--out", "@out"],
        "compare": ["compare", "@a.csv", "--model", str(LAB_CARD), "--at-h", v, "--out", "@out"],
        "card": ["card", "show", str(LAB_CARD), "--rpm", v],
        "campaign": ["campaign", "init", "@out", "--model", str(LAB_CARD), "--controller", str(RECIPE_CTRL),
                     "--target", v],
        "trial": ["trial", str(ROOT / "scenarios" / "trial-lab-recipe.toml"), "--seed", v, "--out", "@out"],
        "calibrate": ["calibrate", str(LAB_CARD), "@a.csv", "--params", v, "--out", "@out"],
        "unknown-flag": ["simulate", str(LAB_CARD), f"--{v}", "1", "--out", "@out"],
        "unknown-command": [v, "x"],
    }[cmd]
    if rng.random() < 0.3:  # a file whose name holds the text
        name = "f" + "".join(c for c in v[:50] if c not in "/\x00")
        files[name] = b"not a card"
        argv = ["card", "show", f"@{name}"]
    return Case("names", f"{cmd}: {v[:12]!r}", argv, files,
                ["--", "argument", "target", "crop", "invalid choice", "card", "calibrate", "a.csv", "f", "bmctl"],
                {"BMCTL_BUDGET_CPU_H": "1e-9"})


# --- crafted campaign databases --------------------------------------------------------------------------------

INJECT = ['<script>alert(1)</script>', '"><img src=x onerror=alert(1)>', "</table><iframe src=//x>",
          "' onmouseover='alert(1)", "<svg onload=alert(1)>", "javascript:alert(1)"]


def _database_case(rng: random.Random) -> Case:
    """A campaign database crafted (not merely damaged): well-formed SQL and JSON with content no verb
    writes -- deep documents, missing or non-finite estimates, markup in text, crafted input paths."""
    ctrl = rng.choice(["recipe", "lqr"])
    op = rng.choice(["est-missing", "est-nan", "est-range", "est-type", "advice-type", "advice-markup",
                     "advice-markup", "text-markup", "text-markup", "sources-markup", "inputs-path", "inputs-path",
                     "inputs-fifo", "huge-text", "est-deep-doc"])
    verb = rng.choice(["status", "advise", "decide", "report", "report", "report", "log"])
    names = ["campaign.sqlite", "inputs", "changed or missing"]
    steps = [_copy_fixture(f"campaign-logged-{ctrl}")]

    def edit_json(table, col, fn, where=""):
        def step(f):
            con = sqlite3.connect(f / "out" / "campaign.sqlite")
            try:
                rows = con.execute(f"SELECT rowid, {col} FROM {table} {where}").fetchall()
                for rowid, text in rows:
                    con.execute(f"UPDATE {table} SET {col} = ? WHERE rowid = ?", (json.dumps(fn(json.loads(text))), rowid))
                con.commit()
            finally:
                con.close()
        return step

    latest = "WHERE t_h = (SELECT MAX(t_h) FROM estimator_states)"
    if op in ("est-missing", "est-nan", "est-range", "est-type"):
        key = rng.choice(["s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c", "s_std_um_q05",
                          "r_mean_q95", "t_h", "ess", "d50_um"])

        def fn(e, key=key, op=op):
            if op == "est-missing":
                e.pop(key, None)
            else:
                e[key] = {"est-nan": rng.choice([float("nan"), float("inf")]), "est-range": rng.choice([-1.0, 1e9, 2.0]),
                          "est-type": rng.choice(["40", [40], {"a": 1}, None, True])}[op]
            return e
        steps.append(edit_json("estimator_states", "estimate", fn, latest if rng.random() < 0.7 else ""))
        label = f"estimate {op} {key}"
        names += ["estimator_states", key]
    elif op in ("advice-type", "advice-markup"):
        key = rng.choice(["next.rpm", "next.mill_min", "next.rest_min", "t_h", "binding", "reachable", "end"])
        val = rng.choice(INJECT) if op == "advice-markup" else rng.choice(["300", None, [1], {"x": 1}, float("nan"), -5])

        def fn(a, key=key, val=val):
            if key == "binding":
                a["binding"] = [val] if isinstance(val, str) else val
            elif key == "reachable":
                a["reachable"] = {val: True} if isinstance(val, str) else val
            elif key == "end":
                a["end"] = {"d50_um": {"median": val, "q05": 1, "q95": 2}}
            elif "." in key:
                a["next"][key.split(".")[1]] = val
            else:
                a[key] = val
            return a
        steps.append(edit_json("plans", "advice", fn))
        label = f"advice {key} = {str(val)[:20]!r}"
        names += ["plans", "advice"]
    elif op == "text-markup":
        col = rng.choice([("actions", "deviation"), ("decisions", "note"), ("particles", "image")])
        steps.append(_sql_args(f"UPDATE {col[0]} SET {col[1]} = ?", rng.choice(INJECT)))
        label = f"{col[0]}.{col[1]} markup"
    elif op == "sources-markup":
        steps.append(_sql_args("UPDATE samples SET sources = ?", json.dumps([rng.choice(INJECT), "a/" + INJECT[0]])))
        label = "samples.sources markup"
    elif op == "huge-text":
        col = rng.choice([("actions", "deviation"), ("decisions", "note")])
        steps.append(_sql_args(f"UPDATE {col[0]} SET {col[1]} = ?", "x" * rng.choice([100_001, 5_000_000])))
        label = f"{col[0]}.{col[1]} huge"
        names += [col[0], col[1]]
    elif op == "est-deep-doc":
        steps.append(edit_json("estimator_states", "estimate", lambda e: {**e, "extra": [[[[1]]]]}))
        label = "estimate with a nested extra entry"
        names += ["estimator_states", "extra"]
    elif op == "inputs-path":
        how = rng.choice(["absolute", "dotdot", "other-key", "not-inputs"])

        def step(f, how=how):
            import hashlib

            other = f / "elsewhere.toml"
            other.write_text(LAB_CARD.read_text(encoding="utf-8") if how != "other-key" else RECIPE_CTRL.read_text(encoding="utf-8"), encoding="utf-8")
            con = sqlite3.connect(f / "out" / "campaign.sqlite")
            inp = json.loads(con.execute("SELECT value FROM meta WHERE key = 'inputs'").fetchone()[0])
            path = {"absolute": str(other), "dotdot": f"inputs/../../{other.name}", "other-key": f"../{other.name}",
                    "not-inputs": "campaign.sqlite"}[how]
            key = "card" if how != "other-key" else "controller"
            inp[key] = {"source": str(other), "file": path, "sha256": hashlib.sha256(
                (f / "out" / path).read_bytes() if how == "not-inputs" else other.read_bytes()).hexdigest()}
            con.execute("UPDATE meta SET value = ? WHERE key = 'inputs'", (json.dumps(inp),))
            con.commit()
            con.close()
        steps.append(step)
        label = f"meta.inputs {how}"
        names += ["meta 'inputs'", "leads outside", "not a file under inputs"]
    else:
        steps.append(lambda f: special_file(rng.choice(["fifo", "/dev/zero"]))(next((f / "out" / "inputs").glob(
            "controller-*.toml"))))
        label = "inputs/controller is a FIFO or /dev/zero"
        names += ["not a regular file"]
    files: dict[str, bytes] = {}
    argv = _verb_argv(rng, verb, files)
    return Case("database", f"{label} on {ctrl}: {verb}", argv, files, names, {"BMCTL_BUDGET_CPU_H": "0.01"},
                setup=_then(*steps), verify=check_campaign if op in ("text-markup", "sources-markup") else None)


SECOND_ROUND = {"nesting": _nesting_case, "special": _special_case, "history": _history_case, "work": _work_case,
                "names": _names_case, "database": _database_case}

KINDS = ("card", "schedule", "scenario", "controller", "table", "image", "flags", "campaign", "resume",
         "nesting", "special", "history", "work", "names", "database")


# --- the checker --------------------------------------------------------------------------------

def _rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="", encoding="utf-8") as fh:
        rd = csv.DictReader(fh)
        return list(rd.fieldnames or []), list(rd)


def _num(x: str) -> float:
    return float(x) if x not in ("", None) else float("nan")


def check_outputs(folder: Path, t_max_c: float = T_MAX_C) -> list[str]:
    """Physical-bounds problems in the outputs under ``folder`` (empty list: all sane).

    moments.csv: s > 0, 0 <= r < 1, std >= 0, temperature in [T_MIN_C, t_max_c], all finite;
    particle tables (m.csv): s in [S_MIN_UM, S_MAX_UM], 0 <= r < 1, area and perimeter > 0;
    estimate tables: finite, ESS >= 1, s > 0 and r in [0, 1) in mean and band; whatif.csv and
    trial trajectories: finite, temperatures in bounds; population.npz: finite and >= 0.
    """
    bad: list[str] = []
    for path in sorted(folder.rglob("*.csv")):
        head, rows = _rows(path)
        name = path.name
        for i, row in enumerate(rows):
            for k, text in row.items():
                if k in ("schedule", "image", "x_um", "y_um", "particle_id") or k is None:
                    continue
                if name == "predicted.csv" and i == len(rows) - 1 and k in ("rpm", "milling", "t_peak_c") and text == "":
                    continue  # design's batch-end row: no action over it, stated empty (bmctl.control.design.predicted_csv)
                try:
                    v = _num(text)
                except (TypeError, ValueError):
                    continue  # text columns
                if not math.isfinite(v):
                    if k.endswith("_q05") or k.endswith("_q95") or k in ("eta_size", "eta_shape") or (
                            k == "ess" and name == "trajectory.csv"):
                        continue  # no sample behind a band: NaN is stated, not nonsense
                    bad.append(f"{name}: row {i + 2}: {k} = {text}")
                    continue
                base = k.removesuffix("_q05").removesuffix("_q95").removeprefix("final_")
                if "temperature" in base and not T_MIN_C <= v <= t_max_c:
                    bad.append(f"{name}: row {i + 2}: {k} = {v:g} outside [{T_MIN_C:g}, {t_max_c:g}] C")
                elif base in ("s_um", "s_mean_um", "s_mode_um") and not S_MIN_UM <= v <= S_MAX_UM:
                    bad.append(f"{name}: row {i + 2}: {k} = {v:g} um outside [{S_MIN_UM:g}, {S_MAX_UM:g}]")
                elif base in ("r", "r_mean", "r_mode") and not 0.0 <= v < 1.0:
                    bad.append(f"{name}: row {i + 2}: {k} = {v:g} outside [0, 1)")
                elif base in ("s_std_um", "r_std", "area_um2", "perimeter_um") and not v >= 0:
                    bad.append(f"{name}: row {i + 2}: {k} = {v:g} < 0")
                elif k == "ess" and not v >= 1.0 - 1e-9:
                    bad.append(f"{name}: row {i + 2}: ess = {v:g} < 1")
            if len(bad) > 5:
                return bad
    for path in sorted(folder.rglob("population.npz")):
        with np.load(path, allow_pickle=False) as z:
            p = z["p"]
            if not np.all(np.isfinite(p)) or p.min() < 0:
                bad.append(f"{path.name}: p has non-finite or negative densities")
    return bad


def _summary_nonsense(stdout: str) -> str | None:
    low = stdout.lower()
    for word in (" nan", "nan ", " inf", "-inf"):
        if word in low:
            return f"stdout has {word.strip()}"
    return None


#: tags and attributes bmctl's HTML pages use (anything else came from an input)
HTML_TAGS = {"html", "head", "meta", "title", "style", "body", "h1", "h2", "h3", "p", "b", "i", "em", "strong", "br",
             "figure", "img", "figcaption", "table", "thead", "tbody", "tr", "th", "td", "ul", "ol", "li", "span",
             "div", "section", "code", "pre", "small", "sup", "sub", "caption", "a", "details", "summary", "dl", "dt",
             "dd", "hr", "header", "footer", "main", "nav", "abbr", "col", "colgroup", "tfoot", "svg", "path"}
HTML_ATTRS = {"lang", "charset", "alt", "src", "class", "id", "title", "colspan", "rowspan", "width", "height",
              "name", "content", "style", "href", "open", "scope", "viewbox", "d", "fill", "stroke", "xmlns"}
#: the longest error line bmctl may print
MAX_ERROR_CHARS = 1000


def outside_out(folder: Path) -> list[str]:
    """Every path under a case folder but outside its ``out`` folder (the harness's own files aside)."""
    found = []
    for p in folder.rglob("*"):
        rel = p.relative_to(folder)
        if rel.parts[0] in ("out", ".stdout", ".stderr"):
            continue
        found.append(str(rel))
    return found


def html_problems(folder: Path) -> list[str]:
    """Markup in an HTML output that bmctl's templates do not write (a tag or an attribute from input)."""
    import html.parser

    class Tags(html.parser.HTMLParser):
        def __init__(self):
            super().__init__()
            self.bad = []

        def handle_starttag(self, tag, attrs):
            if tag not in HTML_TAGS:
                self.bad.append(f"<{tag}>")
            self.bad += [f"{tag} {a}=" for a, v in attrs if a not in HTML_ATTRS or a.startswith("on")
                         or (a in ("src", "href") and v and not v.startswith(("data:image/png;base64,", "#")))]

    bad = []
    for path in sorted(folder.rglob("*.html")):
        t = Tags()
        t.feed(path.read_text(errors="replace", encoding="utf-8"))
        bad += [f"{path.name}: {b}" for b in t.bad[:3]]
    return bad


def _unsafe(case: Case, stdout: str, stderr: str, folder: Path) -> str | None:
    """A write outside ``out``, a sentinel's text in any output, or markup from input in HTML."""
    case_folder = folder.parent
    if case.before is not None and case_folder.exists():
        new = sorted(set(outside_out(case_folder)) - case.before)
        if new:
            return f"wrote outside --out: {', '.join(new[:3])}"
    if case.sentinel:
        if case.sentinel in stdout or case.sentinel in stderr:
            return "a file it was not given was read and quoted"
        for path in folder.rglob("*") if folder.exists() else []:
            if path.is_file() and path.stat().st_size < 50_000_000 and case.sentinel.encode() in path.read_bytes():
                return f"{path.name} holds the text of a file it was not given"
    bad = html_problems(folder) if folder.exists() else []
    if bad:
        return "markup from input in HTML: " + "; ".join(bad)
    return None


def classify(case: Case, rc: int | None, stdout: str, stderr: str, folder: Path) -> tuple[str, str]:
    """Sort one run into :data:`OUTCOMES`; returns (outcome, detail). ``folder`` is the case's
    ``out`` folder (its parent the case folder)."""
    if rc is None:
        return "hang", "time limit"
    if "Traceback" in stderr or rc not in (0, 2):
        tail = stderr.strip().splitlines()[-1] if stderr.strip() else f"exit {rc}"
        return "traceback", tail[:200]
    why = _unsafe(case, stdout, stderr, folder)
    if why:
        return "unsafe", why[:200]
    lines = [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("bmctl: warning:")]
    if rc == 2:
        errs = [ln for ln in lines if ln.startswith("bmctl: error:")]
        if len(errs) != 1 or len(lines) != 1:
            return "unnamed", f"{len(lines)} stderr lines"
        msg = errs[0]
        if len(msg) > MAX_ERROR_CHARS:
            return "unnamed", f"an error line of {len(msg)} characters"
        if any(n and n in msg for n in case.names):
            return "clean", msg[:200]
        return "unnamed", msg[:200]
    bad = check_outputs(folder, case.t_max_c)
    if case.verify is not None and not bad:
        bad = case.verify(folder)
    if bad:
        return "wrote-nonsense", "; ".join(bad[:3])
    why = _summary_nonsense(stdout)
    if why:
        return "accepted-nonsense", why
    if "ess 1," in stdout.lower().replace("min ess 1,", "ess 1,") and "degenerate" not in stderr:
        return "accepted-nonsense", "ESS collapsed to 1 without a warning"
    return "accepted-ok", ""


# --- hostile building blocks of the second round (nesting, special files, crafted arrays) ---------

def deep_toml_value(depth: int = 1000) -> str:
    """A TOML value nested ``depth`` arrays deep."""
    return "[" * depth + "1" + "]" * depth


def deep_json(depth: int = 100_000) -> str:
    """A JSON document nested ``depth`` lists deep."""
    return "[" * depth + "]" * depth


def npy_bomb(shape=(10**12,), dtype: str = "<f8", tail: bytes = b"\0" * 64) -> bytes:
    """A ``.npy`` whose header declares ``shape`` (a few bytes of data behind it)."""
    header = repr({"descr": dtype, "fortran_order": False, "shape": tuple(shape)}).encode()
    pad = 64 - (10 + len(header) + 1) % 64
    header += b" " * pad + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + tail


def npz_with(members: dict[str, bytes]) -> bytes:
    """A zip of raw ``.npy`` members (as ``numpy.savez`` writes them, without checking them)."""
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()
