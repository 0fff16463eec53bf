"""Every command that takes ``--seed`` takes the same range: any non-negative integer (seeds only ever
reach numpy through ``SeedSequence``, which takes integers of any size)."""

import argparse

import numpy as np
import pytest

from bmctl.errors import InputError

from bmctl.cli import build_parser


def _seeded_commands():
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    out = {}
    for name, p in sub.choices.items():
        for a in p._actions:
            if "--seed" in a.option_strings:
                out[name] = a
        for a in p._actions:  # campaign's verbs are one level down
            if isinstance(a, argparse._SubParsersAction):
                for verb, q in a.choices.items():
                    for b in q._actions:
                        if "--seed" in b.option_strings:
                            out[f"{name} {verb}"] = b
    return out


def test_the_seed_flags_exist():
    assert {"simulate", "trial", "whatif", "calibrate", "estimate", "design"} <= set(_seeded_commands())


@pytest.mark.parametrize("name", sorted(_seeded_commands()))
def test_every_seed_flag_takes_a_large_seed_and_refuses_a_negative_one(name):
    action = _seeded_commands()[name]
    big = 2**40 + 3
    assert action.type(str(big)) == big
    np.random.SeedSequence(big)  # what every command hands it to
    with pytest.raises(InputError, match="--seed: must be >= 0"):
        action.type("-1")
