"""``bmctl.measure`` loads its submodules on first use: the campaign's verbs that handle no image
import neither scikit-image nor the renderer (a fresh process each, as the CLI runs them), and every
public name still resolves to the submodule's object."""

from __future__ import annotations

import subprocess
import sys

import pytest

import bmctl.measure as M

HEAVY = ("skimage", "bmctl.measure.render", "bmctl.measure.segment", "bmctl.measure.sampler")


def test_the_campaign_and_its_command_do_not_import_the_image_code():
    probe = ("import sys, bmctl.campaign, bmctl.commands.campaign, bmctl.measure.names, bmctl.measure.tables; "
             f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "", f"imported on start: {out}"


def test_every_public_name_resolves_to_its_submodule_object():
    from bmctl.measure import render, sampler, segment, tables

    where = {"render": render, "sampler": sampler, "segment": segment, "tables": tables}
    assert set(M.__all__) == {"Micrograph", "ParticleTable", "Segmentation", "load_image", "measure_image",
                              "measure_labels", "micrograph_sample", "read_table", "render_micrograph",
                              "segment_image", "write_table"}
    for name in M.__all__:
        module, attr = M._LAZY[name]
        assert getattr(M, name) is getattr(where[module], attr), name
    assert M.segment_image is segment.segment and M.segment is segment  # the module keeps its name
    assert set(M.__all__) <= set(dir(M))
    with pytest.raises(AttributeError, match="no_such_name"):
        M.no_such_name
