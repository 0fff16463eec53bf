"""The CLI starts without importing the numerical stack: building the parser stays light."""

import subprocess
import sys

import pytest

from tests.conftest import ROOT

HEAVY = ("numpy", "scipy", "casadi", "matplotlib", "pydantic")


def _imported_after(code: str) -> list[str]:
    """Run ``code`` in a fresh interpreter and return which HEAVY modules it imported."""
    probe = code + f"\nimport sys\nprint('LOADED:' + ','.join(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True)
    last = out.stdout.strip().splitlines()[-1]
    assert last.startswith("LOADED:")
    return [m for m in last.removeprefix("LOADED:").split(",") if m]


def test_import_cli_and_light_modules_imports_no_numerical_library():
    assert _imported_after("import bmctl, bmctl.cli, bmctl.errors, bmctl.io") == []


def test_building_the_full_parser_imports_no_numerical_library():
    # every subcommand module imported and configured: their heavy imports live inside run()
    assert _imported_after("import bmctl.cli as c\nc.build_parser()") == []


@pytest.mark.parametrize("argv", [["--help"], ["simulate", "--help"], ["design", "--help"], ["measure", "--help"]])
def test_help_imports_no_numerical_library_and_lists_arguments(argv):
    code = ("import bmctl.cli as c\n"
            "try:\n"
            f"    c.main({argv!r})\n"
            "except SystemExit:\n"
            "    pass")
    assert _imported_after(code) == []
    out = subprocess.run([sys.executable, "-m", "bmctl", *argv], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0
    if argv != ["--help"]:
        assert "--out" in out.stdout  # the subcommand's own arguments are shown


def test_measure_default_min_area_matches_the_segmenter():
    from bmctl.commands import measure as cmd
    from bmctl.measure.segment import MIN_AREA_PX

    assert cmd.MIN_AREA_PX == MIN_AREA_PX


def test_campaign_particles_range_matches_the_workflow():
    from bmctl.campaign.workflow import PARTICLES_RANGE
    from bmctl.commands import campaign as cmd

    assert cmd.PARTICLES_RANGE == PARTICLES_RANGE


def test_the_bmctl_process_help_imports_no_numerical_library():
    # main() of the command's own process (argv None) also makes the heap setting: it must stay light
    code = ("import sys\n"
            "sys.argv = ['bmctl', '--help']\n"
            "import bmctl.cli as c\n"
            "try:\n"
            "    c.main()\n"
            "except SystemExit:\n"
            "    pass")
    assert _imported_after(code) == []
