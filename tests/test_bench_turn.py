"""`evsplat bench turn`: each search as seeded against its whole form, the same numbers."""

from __future__ import annotations

import argparse

from evsplat.bench import turn


def test_bench_turn_prints_every_row_and_the_searches_agree(capsys):
    parser = argparse.ArgumentParser()
    turn.add_arguments(parser)
    args = parser.parse_args(["--sizes", "40x30,160x120", "--events", "1500", "--radius", "8"])
    args.repeat = 1
    assert turn.run(args) == 0
    out = capsys.readouterr().out
    assert "| turn images, 40x30 |" in out and "| turn images, 160x120 |" in out
    assert "| ring histograms, 81 centres |" in out
    assert out.count("| True |") == 3
