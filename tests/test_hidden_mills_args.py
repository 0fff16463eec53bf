"""``benchmarks/hidden_mills.py``: bad flags are one line on stderr and exit code 2, before anything is
written or deleted; ``--out`` is taken from the current folder and only a folder the script wrote is
ever emptied."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from bmctl.errors import InputError
from tests.conftest import load_benchmark

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "hidden_mills.py"
#: CPU seconds a refused run may take: a run that got past its checks into the sweeps is stopped here
CPU_S = 30
#: a mill whose vial starts at 79 °C: no target under the ceiling, so a run that accepts its arguments
#: stops after one quick sweep (--particles 200, 0.5 h) with exit code 2
HOT_MILL = ('[[mill]]\nname = "X"\ngamma_mult = 1.2\ndelta_mult = 0.8\nfield = "thermal.ambient_C"\nvalue = 79.0\n'
            'hours = 0.5\nrpm_ref = 300.0\n')


def _run(args, cwd=None, env=None) -> subprocess.CompletedProcess:
    def cap():  # a regression that starts the real campaigns ends here, not minutes later
        resource.setrlimit(resource.RLIMIT_CPU, (CPU_S, CPU_S))

    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120, preexec_fn=cap)


def _tree(folder: Path) -> dict:
    """Every file and folder under ``folder`` with its content (folders: None)."""
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes()) for p in sorted(folder.rglob("*"))}


def _one_line(r: subprocess.CompletedProcess) -> str:
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, (r.returncode, r.stderr[-800:])
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr[-800:]
    assert lines[0].startswith("hidden_mills.py: error: ")
    return lines[0]


@pytest.mark.parametrize("args, flag", [
    (["--sample-every-h", "inf"], "--sample-every-h"),
    (["--sample-every-h", "nan"], "--sample-every-h"),
    (["--sample-every-h", "1e300"], "--sample-every-h"),
    (["--sample-every-h", "1000.5"], "--sample-every-h"),
    (["--sample-particles", "0"], "--sample-particles"),
    (["--sample-particles", "10000000"], "--sample-particles"),
    (["--particles", "1"], "--particles"),
    (["--particles", "1e3"], "--particles"),
    (["--seed", "-1"], "--seed"),
    (["--results-name", "../x"], "--results-name"),
    (["--results-name", ""], "--results-name"),
    (["--cases-typo", "A"], "unrecognized arguments"),
    (["--out", ""], "--out: must name a folder"),
])
def test_a_bad_flag_is_one_line_and_exit_2(tmp_path, args, flag):
    """With ``--cases zz`` (unknown) too: each run is refused at the flag under test, never gets to a sweep."""
    before = _tree(tmp_path)
    line = _one_line(_run(["--cases", "zz", "--no-results", "--out", tmp_path / "out", *args]))
    assert flag in line
    assert _tree(tmp_path) == before  # nothing written or deleted


@pytest.mark.parametrize("cases, says", [
    ("a", "--cases: unknown mill(s) a (known: A, B, C, D, E, F, G, H, I, J, K, L)"),
    ("A,A", "--cases: each mill once (repeated: A)"),
    (",", "--cases: no mill named"),
])
def test_a_bad_cases_list_is_one_line_and_exit_2(tmp_path, cases, says):
    before = _tree(tmp_path)
    assert says in _one_line(_run(["--cases", cases, "--no-results", "--out", tmp_path / "out"]))
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("flag, value", [("--sample-particles", "1000"), ("--seed", "1"), ("--particles", "200")])
def test_a_run_off_the_default_protocol_must_name_its_results(tmp_path, flag, value):
    """A run with another seed or particle count would overwrite results/hidden_mills.json (A-G): refused."""
    before = _tree(tmp_path)
    line = _one_line(_run(["--cases", "A,B,C,D,E,F,G", flag, value, "--out", tmp_path / "out"]))
    assert f"{flag}: name its results (--results-name) or pass --no-results" in line
    assert _tree(tmp_path) == before


def test_noise_off_the_default_must_name_its_results(tmp_path):
    line = _one_line(_run(["--noise", "--seed", "1"], env={**os.environ, "BMCTL_RESULTS_DIR": str(tmp_path)}))
    assert "--seed" in line and "--results-name" in line
    assert not any(tmp_path.iterdir())


def test_figure_of_a_missing_or_foreign_results_file_is_one_line(tmp_path):
    res = tmp_path / "results"
    res.mkdir()
    (res / "other.json").write_text(json.dumps({"command": "x", "repeats": 3}), encoding="utf-8")
    (res / "broken.json").write_text("{", encoding="utf-8")
    env = {**os.environ, "BMCTL_RESULTS_DIR": str(res)}
    png = tmp_path / "f.png"
    before = _tree(tmp_path)
    for name, says in (("zzz", "no results file"), ("../x", "plain file name"),
                       ("other", "not a hidden-mill results file"), ("broken", "not a readable results file")):
        line = _one_line(_run(["--figure", png, "--results-name", name], env=env))
        assert "--results-name" in line and says in line, line
    assert "--figure" in _one_line(_run(["--figure", tmp_path / "f.txt", "--results-name", "zzz"], env=env))
    assert _tree(tmp_path) == before


def test_figure_of_a_results_file_with_step_logs_is_drawn(tmp_path):
    steps = [{"t_h": 0.5 * k, "rpm": 300.0, "mill_min": 30, "plant_s_mean_um": 40.0 + k,
              "estimate_s_mean_um": 40.5 + k} for k in range(4)]
    rec = {"command": "python benchmarks/hidden_mills.py --results-name mine",
           "cases": [{"case": "A", "steps": steps, "target_s_mean_um": 44.0, "final_s_mean_um": 45.0,
                      "error_pct": 2.27}]}
    (tmp_path / "mine.json").write_text(json.dumps(rec), encoding="utf-8")
    r = _run(["--figure", tmp_path / "f.png", "--results-name", "mine.json"],
             env={**os.environ, "BMCTL_RESULTS_DIR": str(tmp_path)})
    assert r.returncode == 0, r.stderr[-800:]
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_shipped_results_files_pass_the_checks_of_figure_and_table():
    hm = load_benchmark("hidden_mills")
    assert hm.read_results("hidden_mills", "--table", ("cases", "summary"))["summary"]
    assert hm.read_results("hidden_mills_unseen", "--results-name", ("cases", "command"))["cases"]


def test_a_non_empty_out_folder_the_script_did_not_write_is_never_deleted(tmp_path):
    """A folder holding a user's file: refused with one line naming --out; before, it was deleted."""
    mills = tmp_path / "mills.toml"
    mills.write_text(HOT_MILL, encoding="utf-8")
    out = tmp_path / "mine"
    out.mkdir()
    (out / "precious.txt").write_text("keep me", encoding="utf-8")
    before = _tree(tmp_path)
    line = _one_line(_run(["--mills", mills, "--particles", 200, "--no-results", "--out", out]))
    assert line.startswith(f"hidden_mills.py: error: --out: {out.resolve()} ") and load_benchmark(
        "hidden_mills").OUT_MARKER in line
    assert _tree(tmp_path) == before


def test_a_relative_out_is_taken_from_the_current_folder(tmp_path):
    """Run from another folder: --out hmout is <that folder>/hmout (named so in the refusal), never the
    repository's; a run stopped before its campaigns creates no folder anywhere."""
    mills = tmp_path / "mills.toml"
    mills.write_text(HOT_MILL, encoding="utf-8")
    (tmp_path / "hmout").mkdir()
    (tmp_path / "hmout" / "precious.txt").write_text("keep me", encoding="utf-8")
    line = _one_line(_run(["--mills", mills, "--particles", 200, "--no-results", "--out", "hmout"], cwd=tmp_path))
    assert f"--out: {(tmp_path / 'hmout').resolve()} holds files" in line
    assert (tmp_path / "hmout" / "precious.txt").read_text(encoding="utf-8") == "keep me"
    line = _one_line(_run(["--mills", mills, "--particles", 200, "--no-results", "--out", "new"], cwd=tmp_path))
    assert "no constant speed" in line  # past every check, stopped before any campaign
    assert not (tmp_path / "new").exists() and not (ROOT / "new").exists()


def test_resolve_out_is_absolute_from_the_current_folder(tmp_path, monkeypatch):
    hm = load_benchmark("hidden_mills")
    monkeypatch.chdir(tmp_path)
    out = hm.resolve_out("hmout")
    assert out.is_absolute() and out == tmp_path.resolve() / "hmout"
    assert hm.resolve_out(str(tmp_path / "a" / ".." / "b")) == tmp_path.resolve() / "b"


def test_out_is_created_emptied_only_when_marked_and_never_otherwise(tmp_path):
    hm = load_benchmark("hidden_mills")
    new = tmp_path / "new" / "deeper"
    assert hm.check_out(new) == new and not new.exists()  # a check writes nothing
    hm.claim_out(new)
    assert [p.name for p in new.iterdir()] == [hm.OUT_MARKER]
    (new / "case-A").mkdir()
    (new / "case-A" / "log.csv").write_text("x", encoding="utf-8")
    (new / "stale.csv").write_text("x", encoding="utf-8")
    hm.claim_out(new)  # an earlier run's folder: emptied, marked again
    assert [p.name for p in new.iterdir()] == [hm.OUT_MARKER]

    empty = tmp_path / "empty"
    empty.mkdir()
    hm.claim_out(empty)
    assert [p.name for p in empty.iterdir()] == [hm.OUT_MARKER]

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "precious.txt").write_text("keep me", encoding="utf-8")
    for fn in (hm.check_out, hm.claim_out):
        with pytest.raises(InputError, match=r"^--out: .*mine holds files this script did not write"):
            fn(mine)
    assert [p.name for p in mine.iterdir()] == ["precious.txt"]

    afile = tmp_path / "afile"
    afile.write_text("x", encoding="utf-8")
    with pytest.raises(InputError, match="exists and is not a folder"):
        hm.check_out(afile)


@pytest.mark.parametrize("name, stem", [("hidden_mills_seed1", "hidden_mills_seed1"), ("x-1.json", "x-1")])
def test_results_name_is_a_plain_name(name, stem):
    assert load_benchmark("hidden_mills").results_name(name) == stem


@pytest.mark.parametrize("name", ["../x", "", ".json", "a/b", "a b", "x\ny", ".hidden"])
def test_results_name_refuses_a_path_or_odd_characters(name):
    with pytest.raises(InputError, match="^--results-name: must be a plain file name"):
        load_benchmark("hidden_mills").results_name(name)


TINY_MILLS = """
[[mill]]
name = "T1"
gamma_mult = 1.3
delta_mult = 0.8
field = "mill.ball_count"
value = 11
hours = 1.0
rpm_ref = 300.0

[[mill]]
name = "T2"
gamma_mult = 0.8
delta_mult = 1.2
field = "mill.ball_to_powder_ratio"
value = 9
hours = 1.0
rpm_ref = 300.0
"""


@pytest.mark.slow
def test_mills_side_by_side_give_the_results_of_one_at_a_time(tmp_path):
    """--workers 2 runs the two mills' campaigns at once; each is seeded by its name and has its own
    folder, so every decision, sample and error is the same as with --workers 1 (advice times aside)."""
    mills = tmp_path / "mills.toml"
    mills.write_text(TINY_MILLS, encoding="utf-8")
    env = {**os.environ, "BMCTL_RESULTS_DIR": str(tmp_path / "results")}
    recs = []
    for n in (1, 2):
        r = subprocess.run([sys.executable, str(SCRIPT), "--mills", str(mills), "--particles", "500", "--workers",
                            str(n), "--out", str(tmp_path / f"o{n}"), "--results-name", f"w{n}"], env=env,
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-2000:]
        recs.append(json.loads((tmp_path / "results" / f"w{n}.json").read_text(encoding="utf-8")))
    import re

    timing = ("advise_", "load_", "wall_s")

    def decisions(case):  # everything but the times (a plan's line, cut to a length, says its solve time)
        out = {k: v for k, v in case.items() if not k.startswith(timing)}
        out["steps"] = [{k: v for k, v in st.items() if k != "plan"} for st in case["steps"]]
        out["plans"] = [re.sub(r"[0-9.]+ ms.*", "", st["plan"]) for st in case["steps"]]
        return out

    assert [c["case"] for c in recs[0]["cases"]] == [c["case"] for c in recs[1]["cases"]] == ["T1", "T2"]
    for c1, c2 in zip(recs[0]["cases"], recs[1]["cases"]):
        assert decisions(c1) == decisions(c2)
