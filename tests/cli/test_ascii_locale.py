"""Under a locale whose encoding is not UTF-8 (``LC_ALL=C``: ASCII), bmctl's files are still UTF-8
(an HTML report declares utf-8; a Latin-1 locale once wrote Latin-1 into it, an ASCII one crashed with
UnicodeEncodeError on '°') and its stdout/stderr never fail on 'µ': a character the terminal's
encoding lacks is written as a ``\\xb5`` escape. Under UTF-8 the output is unchanged."""

import os
import subprocess
import sys

import pytest

from ..conftest import ROOT

LAB = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"


def _ascii_env(**extra) -> dict:
    """The environment of a process whose locale encoding is ASCII (no UTF-8 mode, no coercion)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONIOENCODING", "LC_CTYPE")}
    env.update(LC_ALL="C", LANG="C", PYTHONUTF8="0", PYTHONCOERCECLOCALE="0", **extra)
    return env


def _run(args, env, **kw):
    return subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, timeout=300, **kw)


@pytest.fixture(scope="module")
def ascii_env():
    env = _ascii_env()
    query = "import locale, sys; print(locale.getpreferredencoding(False), sys.stdout.encoding)"
    enc = _run(["-c", query], env).stdout.decode("ascii", "replace").split()
    if any("utf" in e.lower() for e in enc):
        pytest.skip(f"the C locale is UTF-8 here ({enc}): nothing to check")
    return env


def test_write_text_writes_utf8_under_an_ascii_locale(ascii_env, tmp_path):
    out = tmp_path / "t.txt"
    code = f"from bmctl import io; io.write_text({str(out)!r}, '25 \\u00b0C, 40 \\u00b5m\\n')"
    p = _run(["-c", code], ascii_env)
    assert p.returncode == 0, p.stderr.decode("utf-8", "replace")
    assert out.read_bytes() == "25 °C, 40 µm\n".encode("utf-8")


def test_campaign_report_under_an_ascii_locale_is_a_utf8_page(ascii_env, tmp_path):
    from bmctl import campaign as cp

    d = tmp_path / "c"
    cp.init(d, LAB, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    page = tmp_path / "r.html"
    p = _run(["-m", "bmctl", "campaign", "report", str(d), "--out", str(page)], ascii_env)
    err = p.stderr.decode("utf-8", "replace")
    assert p.returncode == 0 and "Traceback" not in err, err
    text = page.read_bytes().decode("utf-8")  # the page's bytes are UTF-8, as its meta declares
    assert "utf-8" in text.lower() and "°" in text


def test_card_show_under_an_ascii_locale_escapes_what_it_cannot_encode(ascii_env):
    p = _run(["-m", "bmctl", "card", "show", str(LAB)], ascii_env)
    err = p.stderr.decode("utf-8", "replace")
    assert p.returncode == 0 and "Traceback" not in err, err
    assert b"\\xb5" in p.stdout  # 'µ' as an escape: the output stays ASCII
    p.stdout.decode("ascii")


def test_help_under_an_ascii_locale(ascii_env):
    p = _run(["-m", "bmctl", "measure", "--help"], ascii_env)
    assert p.returncode == 0 and p.stderr == b"", p.stderr.decode("utf-8", "replace")
    assert b"--scale-bar-um" in p.stdout


def test_utf8_output_is_left_as_it_is():
    """A UTF-8 stdout writes 'µ' itself, not an escape."""
    p = _run(["-m", "bmctl", "card", "show", str(LAB)], _ascii_env(PYTHONIOENCODING="utf-8"))
    assert p.returncode == 0, p.stderr.decode("utf-8", "replace")
    assert "µ".encode("utf-8") in p.stdout and b"\\xb5" not in p.stdout
