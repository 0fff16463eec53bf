"""Strict inputs and safe outputs: lax typing, absurd values, incomplete files, special files,
unbounded work, umask and symlinks. Every bad input gives exit 2 and one line naming the field."""

import os
import re
import stat
import threading

import pytest

from bmctl import io
from bmctl.cli import main
from bmctl.config import load_card
from bmctl.control.config import load_controller
from bmctl.errors import InputError

from tests.conftest import ROOT, card_path

LAB = card_path("alni-1to1-300rpm-lab")
FAN = card_path("alni-1to1-400rpm-fan")


def one_line_error(capsys, args, needle):
    rc = main([str(a) for a in args])
    _, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == 2, err
    assert len(lines) == 1 and lines[0].startswith("bmctl: error:"), err
    assert needle in lines[0], lines[0]
    return lines[0]


def mutated(tmp_path, src, old, new, name="card.toml"):
    text = src.read_text(encoding="utf-8")
    assert old in text, old
    p = tmp_path / name
    p.write_text(text.replace(old, new, 1), encoding="utf-8")
    return p


# --- numbers must be numbers, within physical ranges -----------------------------------------------------

@pytest.mark.parametrize("old, new, field", [
    ("vial_radius_m = 0.0225", 'vial_radius_m = "0.0225"', "mill.vial_radius_m"),
    ("yield_stress_Pa = 78.7e6", "yield_stress_Pa = true", "material.yield_stress_Pa"),
    ("ball_count = 10", "ball_count = 10.0", "mill.ball_count"),
    ("heat_capacity_J_per_K = 400.0", "heat_capacity_J_per_K = 1e-300", "thermal.heat_capacity_J_per_K"),
    ("fracture_hardening_exponent = 1.5", "fracture_hardening_exponent = 1e300", "thermal.fracture_hardening_exponent"),
    ("ambient_C = 25.0", "ambient_C = -273.0", "thermal.ambient_C"),
    ("batch_fraction = 0.05", "batch_fraction = 1e-300", "simulation.batch_fraction"),
    ("vial_height_m = 0.05", "vial_height_m = 0.008", "mill.ball_diameter_m: a 10 mm ball does not fit"),
    ("rpm_max = 600", "rpm_max = 250", "process.rpm"),
])
def test_bad_card_values_are_refused_naming_the_field(tmp_path, capsys, old, new, field):
    p = mutated(tmp_path, LAB, old, new)
    one_line_error(capsys, ["card", "show", p], field)


def test_integers_are_accepted_where_floats_are_expected(tmp_path):
    p = mutated(tmp_path, LAB, "heat_capacity_J_per_K = 400.0", "heat_capacity_J_per_K = 400")
    assert load_card(p).thermal.heat_capacity_J_per_K == 400.0


def test_a_card_saved_with_a_byte_order_mark_is_read(tmp_path):
    """Windows editors may save UTF-8 with a BOM; it is not part of the TOML (it was "Invalid
    statement (at line 1, column 1)")."""
    p = tmp_path / "bom.toml"
    p.write_bytes(b"\xef\xbb\xbf" + open(LAB, "rb").read())
    assert load_card(p).model_dump() == load_card(LAB).model_dump()


def test_schedule_rpm_string_and_huge_segment_are_refused(tmp_path, capsys):
    s = tmp_path / "s.toml"
    s.write_text('[[segment]]\nhours = 1\nrpm = "250"\n', encoding="utf-8")
    one_line_error(capsys, ["simulate", LAB, "--schedule", s, "--out", tmp_path / "o"], "segment[0].rpm")
    s.write_text("[[segment]]\nhours = 1e300\nrpm = 250\n", encoding="utf-8")
    one_line_error(capsys, ["simulate", LAB, "--schedule", s, "--out", tmp_path / "o"], "segment[0].hours")


def test_controller_boolean_string_interval_and_ceiling_are_refused(tmp_path):
    src = ROOT / "controllers" / "mpc-fast.toml"
    text = src.read_text(encoding="utf-8")
    m = re.search(r"^resolve\s*=\s*\w+", text, re.M)
    cases = [(m.group(0), 'resolve = "yes"', "onoff.resolve"),
             ("interval_h = 0.5", "interval_h = 1e-4", "interval_h"),
             ("ceiling_c = 80.0", "ceiling_c = -273.0", "temperature.ceiling_c")]
    for old, new, field in cases:
        p = mutated(tmp_path, src, old, new, "ctrl.toml")
        with pytest.raises(InputError, match=re.escape(field)):
            load_controller(p)


# --- complete files, regular files ---------------------------------------------------------------------

@pytest.mark.parametrize("table", ["thermal", "simulation", "partition", "initial"])
def test_card_missing_a_table_names_it(tmp_path, capsys, table):
    text = LAB.read_text(encoding="utf-8")
    start = text.index(f"[{table}]")
    nxt = text.find("\n[", start + 1)
    p = tmp_path / "card.toml"
    p.write_text(text[:start] + (text[nxt + 1:] if nxt >= 0 else ""), encoding="utf-8")
    one_line_error(capsys, ["card", "show", p], f"[{table}]: required table is missing")


def test_card_truncated_between_tables_is_refused(tmp_path, capsys):
    text = LAB.read_text(encoding="utf-8")
    p = tmp_path / "card.toml"
    p.write_text(text[:text.index("[thermal]")], encoding="utf-8")
    one_line_error(capsys, ["simulate", p, "--out", tmp_path / "o"], "required table is missing")


def test_card_missing_a_field_names_it(tmp_path, capsys):
    p = mutated(tmp_path, LAB, "cooling_time_s = 900.0\n", "")
    one_line_error(capsys, ["card", "show", p], "thermal.cooling_time_s: required field is missing")


def test_fifo_and_device_as_card_fail_at_once(tmp_path, capsys):
    fifo = tmp_path / "card.toml"
    os.mkfifo(fifo)
    done = []
    t = threading.Thread(target=lambda: done.append(main(["card", "show", str(fifo)])), daemon=True)
    t.start()
    t.join(20)
    assert done == [2], "reading a FIFO hung or did not fail"
    err = capsys.readouterr().err
    assert "not a regular file" in err and len(err.strip().splitlines()) == 1
    one_line_error(capsys, ["simulate", "/dev/zero", "--out", tmp_path / "o"], "not a regular file")


def test_oversized_input_is_refused(tmp_path):
    p = tmp_path / "big.toml"
    p.write_bytes(b"#" * 2000)
    with pytest.raises(InputError, match="too large"):
        io.read_input_bytes(p, max_bytes=1000)


# --- bounded work -------------------------------------------------------------------------------------

@pytest.mark.parametrize("flags, needle", [
    (["--hours", "1e9"], "--hours: must be in [1 s, 1000 h]"),
    (["--particles", "1000000000"], "--particles: must be in [100, 10000000]"),
    (["--every", "1e-7"], "--every: must be in [1 s, 1000 h]"),
    (["--hours", "1000", "--every", "0.0003"], "--every: the run would need"),
    (["--hours", "1000", "--particles", "10000000"], "CPU hours"),
])
def test_unbounded_simulate_flags_are_refused(tmp_path, capsys, flags, needle):
    one_line_error(capsys, ["simulate", FAN, *flags, "--out", tmp_path / "o"], needle)
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_estimate_times_beyond_a_batch_are_refused(tmp_path, capsys):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    for p in (a, b):
        p.write_text("s_um,r\n40,0.05\n41,0.06\n", encoding="utf-8")
    one_line_error(capsys, ["estimate", LAB, "--samples", a, b, "--times", "0.5,1e9", "--out", tmp_path / "e.csv"],
                   "--times")


def test_work_budget_is_configurable(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("BMCTL_BUDGET_CPU_H", "1e-6")
    one_line_error(capsys, ["simulate", LAB, "--hours", "1", "--particles", "1000", "--out", tmp_path / "o"],
                   "BMCTL_BUDGET_CPU_H")


# --- outputs -------------------------------------------------------------------------------------------

def test_outputs_honour_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        io.write_text(tmp_path / "a.txt", "x")
        io.write_csv(tmp_path / "b.csv", ["a"], [[1.0]])
    finally:
        os.umask(old)
    for name in ("a.txt", "b.csv"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o644
    old = os.umask(0o077)
    try:
        io.write_text(tmp_path / "c.txt", "x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "c.txt").st_mode) == 0o600


def test_a_symlinked_output_file_stays_a_link(tmp_path):
    target = tmp_path / "real.csv"
    target.write_text("old", encoding="utf-8")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    io.write_text(link, "new")
    assert link.is_symlink() and target.read_text(encoding="utf-8") == "new"


def test_out_through_a_symlink_to_an_unwritable_place_fails_up_front(tmp_path, capsys):
    link = tmp_path / "out"
    link.symlink_to("/proc/no-such-folder")
    one_line_error(capsys, ["simulate", LAB, "--hours", "1", "--out", link], "--out: cannot write")


def test_a_late_write_failure_leaves_no_half_set_and_names_the_real_file(tmp_path):
    (tmp_path / "c.txt").mkdir()  # a folder where a file of the set should go
    with pytest.raises(OSError) as exc:
        with io.output_set():
            io.write_text(tmp_path / "a.txt", "a")
            io.write_text(tmp_path / "b.txt", "b")
            io.write_text(tmp_path / "c.txt", "c")
    assert exc.value.filename == str(tmp_path / "c.txt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.txt"]  # no a, b, nor temporary files


def test_a_failed_write_removes_the_folders_it_made_and_keeps_the_others(tmp_path):
    """A write into new folders that failed (Ctrl-C, a full disk) left them behind, empty."""
    with pytest.raises(KeyboardInterrupt):
        with io.atomic_path(tmp_path / "new" / "deeper" / "a.csv"):
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "kept").mkdir()
    with pytest.raises(OSError):
        with io.output_set():
            io.write_text(tmp_path / "kept" / "x" / "a.txt", "a")
            io.write_text(tmp_path / "y" / "b.txt", "b")
            (tmp_path / "y" / "user.txt").write_text("not ours", encoding="utf-8")  # put there meanwhile
            raise OSError(28, "No space left on device", "c.txt")
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == ["kept", "y", "y/user.txt"]
    with io.output_set():  # a set that succeeds keeps what it made
        io.write_text(tmp_path / "z" / "c.txt", "c")
    assert (tmp_path / "z" / "c.txt").read_text(encoding="utf-8") == "c"


@pytest.mark.slow
def test_simulate_with_an_output_name_that_is_a_folder_writes_nothing(tmp_path, capsys):
    out = tmp_path / "o"
    (out / "moments.png").mkdir(parents=True)
    line = one_line_error(capsys, ["simulate", LAB, "--hours", "1", "--particles", "200", "--out", out,
                                   "--no-progress"], "moments.png")
    assert ".moments.png." not in line
    assert sorted(p.name for p in out.iterdir()) == ["moments.png"]


@pytest.mark.slow
def test_run_leaving_the_validity_range_warns(tmp_path, capsys):
    if "[validity]" in LAB.read_text(encoding="utf-8"):
        p = mutated(tmp_path, LAB, "[validity]", "[validity]\ntemperature_max_C = 30.0\n#")
    else:
        p = mutated(tmp_path, LAB, "[stochastic]", "[validity]\ntemperature_max_C = 30.0\n\n[stochastic]")
    rc = main(["simulate", str(p), "--hours", "1", "--particles", "200", "--out", str(tmp_path / "o"),
               "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 0 and "warning" in err and "above the card's maximum 30 °C" in err


def test_a_ball_count_whose_derived_ratio_is_absurd_names_both_fields(tmp_path):
    """400 balls over 2.7 g of powder: the message names what the user wrote (the ball count and the
    powder mass), not only the derived ratio's pydantic bound."""
    import re as _re

    from tests.config.test_own_mill import doc_card

    p = doc_card(tmp_path)
    p.write_text(_re.sub(r"ball_count = \d+", "ball_count = 400", p.read_text(encoding="utf-8")), encoding="utf-8")
    with pytest.raises(InputError, match=r"mill.ball_count, powder.mass_kg: 400 balls .* ratio of 1059"):
        load_card(p)
