"""Hostile-input cases for the ``bmctl`` CLI and a checker of what it does with them.

Shared by the seeded property test (tests/test_fuzz.py, Hypothesis draws the case seeds) and
the long run (benchmarks/fuzz.py, each case in a forked subprocess). A case is a command line
built around one mutated input -- a model card, a schedule, a scenario, a controller, a
particle table, a micrograph or a flag -- plus the names an error message about it may use.
:func:`classify` sorts what the CLI did into the outcomes of docs/reliability.md:

``clean``            exit 2, one stderr line naming the file, flag or field
``accepted-ok``      exit 0, every output within physical bounds
``accepted-nonsense`` exit 0, but the printed summary is not finite or physical
``wrote-nonsense``   exit 0, an output file outside physical bounds
``traceback``        any other exception or exit status
``hang``             the per-case time limit ran out
``unnamed``          exit 2 without naming the file, flag or field (or more than one line)
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
import random
import struct
import tomllib
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CARDS = sorted(p for p in (ROOT / "models").glob("*.toml") if not p.name.endswith(".moments.toml"))
CONTROLLERS = sorted((ROOT / "controllers").glob("*.toml"))
OUTCOMES = ("clean", "accepted-ok", "accepted-nonsense", "wrote-nonsense", "traceback", "hang", "unnamed")
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
    op = rng.choice(["delete", "swap", "swap", "swap", "truncate", "garbage", "drop-table", "unknown-key", "swap2"])
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

    def write(self, folder: Path) -> list[str]:
        """Write the case's files under ``folder``; returns argv with paths made absolute."""
        for name, data in self.files.items():
            (folder / name).write_bytes(data)
        return [a.replace("@", str(folder) + "/") for a in self.argv]


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
every_h = 0.25
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
        data, names, label = mutate_toml(rng, src.read_text())
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
        data, names, label = mutate_toml(rng, src.read_text())
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
    raise ValueError(kind)


FLAG_VALUES = ["0", "-1", "1e-300", "1e300", "nan", "inf", "1e9", "abc", "", "1e-7", "0.5", "10"]


def _flag_case(rng: random.Random, out: str) -> Case:
    card = str(_card(rng))
    cmd = rng.choice(["simulate", "simulate", "estimate", "whatif", "measure", "design", "identify"])
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
    else:
        flag = rng.choice(["--particles", "--random-schedules", "--seed"])
        args = {"--particles": "200", "--random-schedules": "0"}
        args[flag] = v
        argv = ["identify", card, "--quick", "--quiet", *sum(([k, a] for k, a in args.items()), []),
                "--out", "@c.moments.toml"]
        env["BMCTL_BUDGET_CPU_H"] = "1e-9"
    return Case("flags", f"{cmd} {flag} {v!r}", argv, files, [flag, "BMCTL_BUDGET", "a.csv", "b.csv", "img.png", "s.toml"],
                env)



KINDS = ("card", "schedule", "scenario", "controller", "table", "image", "flags")


# --- the checker --------------------------------------------------------------------------------

def _rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="") as fh:
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
                try:
                    v = _num(text)
                except (TypeError, ValueError):
                    continue  # text columns
                if not math.isfinite(v):
                    if k.endswith("_q05") or k.endswith("_q95") or k in ("eta_size", "eta_shape"):
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


def classify(case: Case, rc: int | None, stdout: str, stderr: str, folder: Path) -> tuple[str, str]:
    """Sort one run into :data:`OUTCOMES`; returns (outcome, detail)."""
    if rc is None:
        return "hang", "time limit"
    if "Traceback" in stderr or rc not in (0, 2):
        tail = stderr.strip().splitlines()[-1] if stderr.strip() else f"exit {rc}"
        return "traceback", tail[:200]
    lines = [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("bmctl: warning:")]
    if rc == 2:
        errs = [ln for ln in lines if ln.startswith("bmctl: error:")]
        if len(errs) != 1 or len(lines) != 1:
            return "unnamed", f"{len(lines)} stderr lines"
        msg = errs[0]
        if any(n and n in msg for n in case.names):
            return "clean", msg[:200]
        return "unnamed", msg[:200]
    bad = check_outputs(folder, case.t_max_c)
    if bad:
        return "wrote-nonsense", "; ".join(bad[:3])
    why = _summary_nonsense(stdout)
    if why:
        return "accepted-nonsense", why
    if "ess 1," in stdout.lower().replace("min ess 1,", "ess 1,") and "degenerate" not in stderr:
        return "accepted-nonsense", "ESS collapsed to 1 without a warning"
    return "accepted-ok", ""
