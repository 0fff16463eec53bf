"""`bmctl estimate` and `bmctl compare` inputs: how sample files are matched to times, messages."""

from __future__ import annotations

import numpy as np

from bmctl.cli import main

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


def _table(path, seed):
    rng = np.random.default_rng(seed)
    s, r = rng.uniform(30, 90, 60), rng.uniform(0.05, 0.4, 60)
    path.write_text("s_um,r\n" + "".join(f"{a:.3f},{b:.4f}\n" for a, b in zip(s, r)), encoding="utf-8")


def test_folder_whose_name_order_is_not_its_number_order_warns(tmp_path, capsys):
    """run-10h.csv sorts before run-2h.csv by name: the times then go to the wrong files, said on stderr."""
    bad, good = tmp_path / "bad", tmp_path / "good"
    for folder, names in ((bad, ("run-1h", "run-2h", "run-10h")), (good, ("run-01h", "run-02h", "run-10h"))):
        folder.mkdir()
        for i, name in enumerate(names):
            _table(folder / f"{name}.csv", i)
    for folder, warned in ((bad, True), (good, False)):
        rc = main(["estimate", LAB, "--samples", str(folder), "--times", "0.1,0.2,0.3", "--particles", "100",
                   "--no-progress", "--out", str(tmp_path / folder.name / "o" / "e.csv")])
        _, err = capsys.readouterr()
        assert rc == 0, err
        assert ("run-10h.csv at 0.1 h" in err) is warned, err
