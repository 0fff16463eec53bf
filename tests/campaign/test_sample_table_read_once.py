"""A campaign sample's particle table is read once for its particles and their images and centroids:
it was read twice (``read_table`` then ``read_locations``), so a table replaced in between (a
``bmctl measure`` writing the file again) could pair one table's particles with another's locations."""

from __future__ import annotations

import numpy as np


def test_a_sample_table_is_read_once_for_particles_and_locations(tmp_path, monkeypatch):
    import bmctl.io
    from bmctl.campaign.advice import _measure

    table = tmp_path / "sample.csv"
    table.write_text("image,x_um,y_um,s_um,r\na.png,1.5,2.0,40.0,0.02\nb.png,3.0,,55.5,0.10\n", encoding="utf-8")
    reads = []
    real = bmctl.io.read_input_bytes

    def counting(path, *a, **kw):
        reads.append(str(path))
        return real(path, *a, **kw)

    monkeypatch.setattr(bmctl.io, "read_input_bytes", counting)
    pooled, images, x_um, y_um, reports, counts = _measure([table], None)
    assert reads.count(str(table)) == 1
    assert pooled.s_um.tolist() == [40.0, 55.5] and counts == [2]
    assert images == ["a.png", "b.png"]
    assert x_um.tolist() == [1.5, 3.0] and y_um[0] == 2.0 and np.isnan(y_um[1])  # an empty centroid is NaN
