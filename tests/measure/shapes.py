"""Small test images and a CLI runner shared by the measure tests."""

from __future__ import annotations

import numpy as np

from bmctl.cli import main


def discs(size: int = 128) -> np.ndarray:
    """A gray uint8 image: nine bright discs (radius 7 px) on a dark background."""
    img = np.full((size, size), 30, np.uint8)
    yy, xx = np.mgrid[:size, :size]
    for cy in (24, 64, 104):
        for cx in (24, 64, 104):
            img[(yy - cy) ** 2 + (xx - cx) ** 2 <= 49] = 220
    return img


def cli(capsys, argv):
    """``bmctl ARGV``: exit code, stdout, stderr."""
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err
