"""`evsplat bench paper` writes the three tables with the paper's numbers beside ours, and keeps
hand-recorded full-size sections when it regenerates docs/results.md."""

from __future__ import annotations

import argparse
import json

import pytest

import evsplat.bench.paper as paper
from evsplat.sweep import SweepResult


def _fake_row(cell):
    case, variant = cell.labels["case"], cell.labels["variant"]
    speed = int(case.rsplit("-x", 1)[1])
    psnr = {"static": 15.0, "no-motion-losses": 16.0}.get(variant, 18.0 + speed)
    return {
        **cell.labels,
        "seed": cell.seed,
        "host": "hostA",
        "adapter": "GPU A (DiscreteGpu, Vulkan)",
        "iterations": cell.config["schedule"]["iterations"],
        "wall_seconds": 1.0 + len(variant),
        "iterations_per_second": 7.0,
        "peak_rss_mib": 1.0,
        "gaussians": 10,
        "psnr": psnr,
        "ssim": 0.5,
        "lpips": None,
        "psnr_moving": psnr - 3,
        "psnr_flat": 12.0,
        "psnr_moving_flat": 9.0,
        "track_px": 1.0 + speed,
    }


def _fake_sweep(calls: list, change: dict | None = None):
    """The sweep runner without training: one made-up row per cell, the cells recorded."""

    def sweep(cells, out, options):
        calls.extend(cells)
        return SweepResult(rows=[{**_fake_row(c), **(change or {})} for c in cells])

    return sweep


@pytest.fixture(autouse=True)
def no_simulation(monkeypatch):
    monkeypatch.setattr(paper, "simulate_cases", lambda cases, out: {c.name: out for c in cases})


def _args(tmp_path, doc, tables, seeds="0"):
    return argparse.Namespace(
        full_size=False,
        iters=7,
        out=tmp_path / "b",
        doc=doc,
        tables=tables,
        seeds=seeds,
        ray=None,
        jobs=1,
        max_retries=3,
        cpus_per_cell=1.0,
        fresh=False,
        device="auto",
    )


def test_tables_hold_every_run_and_the_papers_numbers(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(paper, "run_sweep", _fake_sweep(calls))
    doc = tmp_path / "results.md"
    doc.write_text("# old\n\n## Full-size runs\n\nball 400x400: kept\n")
    assert paper.run(_args(tmp_path, doc, "1,2,3")) == 0
    # 4 scenes x 3 variants + speeds 2-4 + 4 ablation rows; ball x1 full is shared.
    assert len(calls) == 12 + 3 + 4
    assert len({(c.labels["case"], c.labels["variant"]) for c in calls}) == len(calls)
    text = doc.read_text()
    assert "| butterfly | 24.27 / 0.902 / 0.12 | 12.00 |" in text
    assert "| 9.00 / 12.00 / 16.00 | 2.0 / 2.0 |" in text  # flat, static, full; tracking
    assert "| x3 | 19.14 | 21.00 (12.00) | 0.500 | 18.00 (9.00) | 4.0 |" in text
    assert "| L_e | 18.61 | 19.00 (12.00) |" in text
    runs_on = "; 7 iterations per run; seed 0; run on hostA (GPU A (DiscreteGpu, Vulkan))."
    assert text.count(runs_on) == 3
    assert text.rstrip().endswith("ball 400x400: kept")
    assert (tmp_path / "results_pareto.png").stat().st_size > 0


def test_rerunning_one_table_keeps_the_others_as_measured(tmp_path, monkeypatch):
    monkeypatch.setattr(paper, "run_sweep", _fake_sweep([]))
    doc = tmp_path / "results.md"
    args = _args(tmp_path, doc, "1,3")
    assert paper.run(args) == 0
    first = doc.read_text()
    table1 = first[first.index(paper.TITLES["1"]) : first.index(paper.TITLES["3"])]
    monkeypatch.setattr(paper, "run_sweep", _fake_sweep([], {"psnr": 30.0}))
    args.tables = "3"
    assert paper.run(args) == 0
    text = doc.read_text()
    assert table1 in text  # untouched, provenance line included
    assert paper.TITLES["2"] not in text  # never measured, not invented
    assert "| L_e | 18.61 | 30.00 (12.00) |" in text
    assert "| L_e | 18.61 | 30.00 (12.00) |" not in first
    assert text.index(paper.TITLES["1"]) < text.index(paper.TITLES["3"]) < text.index("![time")
    # results.json (and the figure drawn from it) holds both runs' cells, table 3's the new ones.
    rows = json.loads((args.out / "results.json").read_text())["rows"]
    assert len(rows) == 12 + 4  # table 1's cells, then table 3's (ball x1 full shared)
    assert sorted(r["psnr"] for r in rows if r["variant"] == "e") == [30.0]


def test_several_seeds_give_each_cell_its_mean_and_standard_deviation(tmp_path, monkeypatch):
    calls = []

    def sweep(cells, out, options):
        calls.extend(cells)
        rows = [_fake_row(c) for c in cells]
        for r in rows:  # seeds 0, 1, 5: PSNR +0, +1, +5 (mean +2, sample sd sqrt(7))
            r["psnr"] += r["seed"]
            r["host"] = f"host{r['seed']}"
        return SweepResult(rows=rows)

    monkeypatch.setattr(paper, "run_sweep", sweep)
    doc = tmp_path / "new" / "results.md"  # a folder that does not exist yet
    assert paper.run(_args(tmp_path, doc, "3", seeds="0,1,5")) == 0
    assert len(calls) == 3 * 5 and sorted({c.seed for c in calls}) == [0, 1, 5]
    text = doc.read_text()
    # L_e: 19 + seed -> 21.00 +- 2.65; the unchanged metrics have no spread; flat stays plain.
    assert "| L_e | 18.61 | 21.00 ± 2.65 (12.00) | 0.500 ± 0.000 | 16.00 ± 0.00 (9.00) | " in text
    assert "mean ± sd over seeds 0,1,5; run on host0, host1, host5 (GPU A" in text
    with pytest.raises(paper.EvsplatError, match="--seeds"):
        paper.run(_args(tmp_path, doc, "3", seeds="0,x"))
