"""`evsplat bench turn`: each search as seeded against its whole form, the same numbers."""

from __future__ import annotations

import argparse

import pytest

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


def test_a_size_that_is_not_width_by_height_is_a_one_line_error(capsys):
    parser = argparse.ArgumentParser(prog="evsplat bench turn")
    turn.add_arguments(parser)
    with pytest.raises(SystemExit) as stop:
        parser.parse_args(["--sizes", "96x96,10"])
    assert stop.value.code == 2
    assert "'96x96,10' is not WIDTHxHEIGHT" in capsys.readouterr().err
