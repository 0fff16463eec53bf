"""The campaign verbs' refusals name what the caller gave: from Python the argument (``hours``,
``temperature_max_c``, ``accept=False``), from ``bmctl campaign`` the flag (``--hours``,
``--temperature-max-c``, ``--reject``), one line each, nothing recorded.

The verbs name an argument through :func:`bmctl.campaign.workflow.arg`; the command runs them
within :func:`bmctl.campaign.workflow.naming` with its table :data:`bmctl.commands.campaign.FLAGS`."""

from __future__ import annotations

import argparse
import json
import re
import shutil
from pathlib import Path

import pytest

from bmctl import campaign as cp
from bmctl.campaign import db
from bmctl.campaign.workflow import arg, naming
from bmctl.cli import main
from bmctl.commands import campaign as command
from bmctl.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
LQR = ROOT / "controllers" / "lqr-baseline.toml"
TABLE = ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv"


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A 2-h recipe campaign (nothing logged), and one with 0.5 h logged and an advice at its end."""
    base = tmp_path_factory.mktemp("names")
    fresh, advised = base / "fresh", base / "advised"
    cp.init(fresh, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    shutil.copytree(fresh, advised)
    cp.log(advised, 300.0, 0.5)
    cp.advise(advised)
    return {"fresh": fresh, "advised": advised}


@pytest.fixture
def unusable(tmp_path):
    """A particle table whose ``measure.json`` gives its image the verdict unusable."""
    d = tmp_path / "measured"
    d.mkdir()
    shutil.copyfile(TABLE, d / "t.csv")
    (d / "measure.json").write_text(json.dumps({"table": "t.csv", "inputs": [
        {"image": "a.png", "verdict": {"value": "unusable", "reasons": ["most of the foreground unmeasured"]}}]}),
        encoding="utf-8")
    return d / "t.csv"


def _copy(made, which, tmp_path) -> Path:
    d = tmp_path / which
    shutil.copytree(made[which], d)
    return d


def _counts(d) -> dict:
    return cp.status(d)["counts"]


# (case, campaign to start from ("fresh", "advised") or None for init, the Python call, its message's
# start, the command line after `bmctl campaign` (None: the command's own parsing refuses it first),
# that message's start)
CASES = [
    ("init-hours", None, lambda d: cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=0.05, particles=100),
     "hours: a batch of 0.05 h (3 min) is shorter",
     lambda d: ["init", d, "--model", CARD, "--controller", RECIPE, "--target", "d50_um=45", "--hours", "0.05"],
     "--hours: a batch of 0.05 h (3 min) is shorter"),
    ("init-hours-range", None, lambda d: cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=1e300),
     "hours: must be <= 1000 (got 1e+300)", None, None),
    ("init-temperature-max-c", None,
     lambda d: cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, temperature_max_c=20.0, particles=100),
     "temperature_max_c: 20 °C is not above the card's ambient temperature",
     lambda d: ["init", d, "--model", CARD, "--controller", RECIPE, "--target", "d50_um=45", "--hours", "2",
                "--temperature-max-c", "20"],
     "--temperature-max-c: 20 °C is not above the card's ambient temperature"),
    ("init-particles", None, lambda d: cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=10),
     "particles: must be >= 50 (got 10)", None, None),
    ("init-target", None, lambda d: cp.init(d, CARD, LQR, {"d50_um": 45.0}, hours=2.0, particles=100),
     "target: names d50_um, never s_mean_um, the moment the LQR tracks",
     lambda d: ["init", d, "--model", CARD, "--controller", LQR, "--target", "d50_um=45", "--hours", "2"],
     "--target: names d50_um, never s_mean_um, the moment the LQR tracks"),
    ("log-rpm", "fresh", lambda d: cp.log(d, 1500.0, 0.5),
     "rpm 1500: above the mill's rpm_max",
     lambda d: ["log", d, "--rpm", "1500", "--hours", "0.5"], "--rpm 1500: above the mill's rpm_max"),
    ("log-milling", "fresh", lambda d: cp.log(d, 300.0, 0.5, milling=0.001),
     "milling 0.001 of hours 0.5: ",
     lambda d: ["log", d, "--rpm", "300", "--hours", "0.5", "--milling", "0.001"], "--milling 0.001 of --hours 0.5: "),
    ("log-temperature-c", "fresh", lambda d: cp.log(d, 300.0, 0.5, temperature_c=500.0),
     "temperature_c: must be <= 400 (got 500.0)",
     lambda d: ["log", d, "--rpm", "300", "--hours", "0.5", "--temperature-c", "500"],
     "--temperature-c: must be <= 400 (got 500.0)"),
    ("log-gap", "fresh", lambda d: cp.log(d, 300.0, 0.5, from_h=1.0),
     "from_h 1: leaves a gap after 0 h; log what the mill did from 0 h first (a rest is rpm 0)",
     lambda d: ["log", d, "--rpm", "300", "--hours", "0.5", "--from-h", "1"],
     "--from-h 1: leaves a gap after 0 h; log what the mill did from 0 h first (a rest is --rpm 0)"),
    ("log-overlap", "advised", lambda d: cp.log(d, 300.0, 0.5, from_h=0.25),
     "from_h 0.25: overlaps the logged interval ending at 0.5 h",
     lambda d: ["log", d, "--rpm", "300", "--hours", "0.5", "--from-h", "0.25"],
     "--from-h 0.25: overlaps the logged interval ending at 0.5 h"),
    ("log-batch-end", "fresh", lambda d: cp.log(d, 300.0, 3.0),
     "hours 3: ends at 3 h, after the batch end (2 h)",
     lambda d: ["log", d, "--rpm", "300", "--hours", "3"], "--hours 3: ends at 3 h, after the batch end (2 h)"),
    ("sample-at-h", "fresh", lambda d: cp.sample(d, 5.0, [TABLE]),
     "at_h 5: after the batch end (2 h)",
     lambda d: ["sample", d, "--at-h", "5", TABLE], "--at-h 5: after the batch end (2 h)"),
    ("sample-at-h-text", "fresh", lambda d: cp.sample(d, "0.5", [TABLE]), "at_h: not a number (", None, None),
    ("sample-um-per-px", "fresh", lambda d: cp.sample(d, 0.5, [TABLE], um_per_px=1e9),
     "um_per_px: 1e+09 µm is outside the sane range",
     lambda d: ["sample", d, "--at-h", "0.5", TABLE, "--um-per-px", "1e9"],
     "--um-per-px: 1e+09 µm is outside the sane range"),
    ("decide-accept-with-rpm", "advised", lambda d: cp.decide(d, True, rpm=250.0),
     "decide: rpm/milling go with accept=False (an accepted advice is run as recommended)",
     lambda d: ["decide", d, "--accept", "--rpm", "250"],
     "decide: --rpm/--milling go with --reject (an accepted advice is run as recommended)"),
    ("decide-rpm", "advised", lambda d: cp.decide(d, False, rpm=1500.0),
     "rpm 1500: above the mill's rpm_max",
     lambda d: ["decide", d, "--reject", "--rpm", "1500"], "--rpm 1500: above the mill's rpm_max"),
    ("decide-milling", "advised", lambda d: cp.decide(d, False, milling=2.0),
     "milling: must be <= 1 (got 2.0)", None, None),
    ("report-out", "advised", lambda d: cp.report(d, d / db.DB_NAME),
     "out: ", lambda d: ["report", d, "--out", d / db.DB_NAME], "--out: "),
]
IDS = [c[0] for c in CASES]
CLI_CASES = [c for c in CASES if c[4] is not None]


def _refusal(call) -> str:
    with pytest.raises(InputError) as exc:
        call()
    return str(exc.value)


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_a_python_call_is_refused_naming_its_argument(made, tmp_path, case):
    _, start, call, python, *_ = case
    d = tmp_path / "c" if start is None else _copy(made, start, tmp_path)
    before = None if start is None else _counts(d)
    msg = _refusal(lambda: call(d))
    assert msg.startswith(python) and "--" not in msg and "\n" not in msg, msg
    if start is None:
        assert not d.exists()
    else:
        assert _counts(d) == before


@pytest.mark.parametrize("case", CLI_CASES, ids=[c[0] for c in CLI_CASES])
def test_the_command_is_refused_naming_its_flag(made, tmp_path, capsys, case):
    _, start, _, _, argv, flagged = case
    d = tmp_path / "c" if start is None else _copy(made, start, tmp_path)
    before = None if start is None else _counts(d)
    capsys.readouterr()
    assert main(["campaign", *map(str, argv(d))]) == 2
    captured = capsys.readouterr()
    err = captured.err.splitlines()
    assert len(err) == 1 and err[0].startswith("bmctl: error: " + flagged), err
    assert "Traceback" not in captured.err
    if start is None:
        assert not d.exists()
    else:
        assert _counts(d) == before


def test_an_unusable_image_is_refused_naming_the_way_to_accept_it(made, tmp_path, capsys, unusable):
    d = _copy(made, "fresh", tmp_path)
    msg = _refusal(lambda: cp.sample(d, 0.5, [unusable]))
    assert msg.startswith("a.png: verdict unusable (most of the foreground unmeasured)") and \
        msg.endswith("or pass accept_unusable=True"), msg
    capsys.readouterr()
    assert main(["campaign", "sample", str(d), "--at-h", "0.5", str(unusable)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].endswith("or pass --accept-unusable"), err
    assert _counts(d)["samples"] == 0
    assert cp.sample(d, 0.5, [unusable], accept_unusable=True)["n"] > 0  # as the message says


def test_prose_is_not_renamed(made, tmp_path, capsys):
    """Only the arguments are named as flags: the rest of a message (`h`, `rpm_max`, `batch end`) is
    the same text from Python and from the command."""
    d = _copy(made, "fresh", tmp_path)
    msg = _refusal(lambda: cp.log(d, 1500.0, 0.5))
    capsys.readouterr()
    assert main(["campaign", "log", str(d), "--rpm", "1500", "--hours", "0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "bmctl: error: --" + msg, (err, msg)


def test_the_flag_names_end_with_the_command(made, tmp_path, capsys):
    """A Python call after a refused command (and after a block that raised) names its argument."""
    d = _copy(made, "fresh", tmp_path)
    assert main(["campaign", "log", str(d), "--rpm", "1500", "--hours", "0.5"]) == 2
    capsys.readouterr()
    assert _refusal(lambda: cp.log(d, 1500.0, 0.5)).startswith("rpm 1500: ")
    with pytest.raises(InputError, match="^--rpm 1500: "):
        with naming(command.FLAGS):
            cp.log(d, 1500.0, 0.5)
    assert arg("rpm") == "rpm" and arg("accept=False") == "accept=False"


def _named_in_source() -> set[str]:
    """Every argument the campaign's modules name through ``arg("...")``."""
    call = re.compile(r"""\barg\((["'])([^"']+)\1\)""")
    return {m.group(2) for mod in ("workflow", "advice")
            for m in call.finditer((ROOT / "bmctl" / "campaign" / f"{mod}.py").read_text(encoding="utf-8"))}


def _options() -> dict[str, set[str]]:
    """Each campaign verb's option strings, as its parser defines them."""
    parser = argparse.ArgumentParser()
    command.configure(parser)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {verb: {s for a in p._actions for s in a.option_strings} for verb, p in sub.choices.items()}


def test_every_argument_a_message_names_has_its_flag():
    """The table covers every argument the verbs name (one it lacked would be named as in Python on
    the command line), and each flag is one the command takes."""
    named = _named_in_source()
    assert {"hours", "rpm", "at_h", "out", "accept=False", "accept_unusable=True"} <= named
    assert named <= set(command.FLAGS), named - set(command.FLAGS)
    flags = set().union(*_options().values())
    assert set(command.FLAGS.values()) <= flags, set(command.FLAGS.values()) - flags
    for name, flag in command.FLAGS.items():  # an argument's flag is its name, dashed (a switch: its value's flag)
        if "=" not in name:
            assert flag == "--" + name.replace("_", "-"), (name, flag)
