"""`evsplat bench paper` writes the three tables with the paper's numbers beside ours, and keeps
hand-recorded full-size sections when it regenerates docs/results.md."""

from __future__ import annotations

import argparse

import evsplat.bench.paper as paper


def _fake_run(case, variant, spec, out, iters):
    psnr = {"static": 15.0, "no-motion-losses": 16.0}.get(variant, 18.0 + case.speed)
    return {
        "case": case.name,
        "variant": variant,
        "iterations": 7,
        "wall_seconds": 1.0 + len(variant),
        "iterations_per_second": 7.0,
        "peak_rss_mib": 1.0,
        "gaussians": 10,
        "psnr": psnr,
        "ssim": 0.5,
        "lpips": None,
        "psnr_moving": psnr - 3,
    }


def test_tables_hold_every_run_and_the_papers_numbers(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(paper, "run_one", lambda *a: calls.append(a[:2]) or _fake_run(*a))
    doc = tmp_path / "results.md"
    doc.write_text("# old\n\n## Full-size runs\n\nball 400x400: kept\n")
    args = argparse.Namespace(full_size=False, iters=7, out=tmp_path / "b", doc=doc, tables="1,2,3")
    assert paper.run(args) == 0
    # 4 scenes x 3 variants + speeds 2-4 + 4 ablation rows; ball x1 full is shared.
    assert len(calls) == 12 + 3 + 4
    text = doc.read_text()
    assert "| butterfly | 24.27 / 0.902 / 0.12 |" in text
    assert "| x3 | 19.14 | 21.00 |" in text
    assert "| L_e | 18.61 | 19.00 |" in text
    assert text.count("; 7 iterations per run.") == 3
    assert text.rstrip().endswith("ball 400x400: kept")
    assert (tmp_path / "results_pareto.png").stat().st_size > 0


def test_rerunning_one_table_keeps_the_others_as_measured(tmp_path, monkeypatch):
    monkeypatch.setattr(paper, "run_one", lambda *a: _fake_run(*a))
    doc = tmp_path / "results.md"
    args = argparse.Namespace(full_size=False, iters=7, out=tmp_path / "b", doc=doc, tables="1,3")
    assert paper.run(args) == 0
    first = doc.read_text()
    table1 = first[first.index(paper.TITLES["1"]) : first.index(paper.TITLES["3"])]
    monkeypatch.setattr(paper, "run_one", lambda *a: {**_fake_run(*a), "psnr": 30.0})
    args.tables = "3"
    assert paper.run(args) == 0
    text = doc.read_text()
    assert table1 in text  # untouched, provenance line included
    assert paper.TITLES["2"] not in text  # never measured, not invented
    assert "| L_e | 18.61 | 30.00 |" in text and "| L_e | 18.61 | 30.00 |" not in first
    assert text.index(paper.TITLES["1"]) < text.index(paper.TITLES["3"]) < text.index("![time")
