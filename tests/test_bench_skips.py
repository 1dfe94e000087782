"""`evsplat bench skips` pairs runs that differ in one skip, passes each variant's config change
and train arguments to the run, and replaces only its own section of docs/results.md."""

from __future__ import annotations

import argparse

import evsplat.bench.skips as skips
from evsplat.config import TrainConfig
from evsplat.sweep import SweepResult


def _fake_row(cell) -> dict:
    cfg = TrainConfig.from_dict(cell.config)
    # Time follows what the variant switched off, so the table's arithmetic can be checked.
    wall = 50.0 if not cfg.deform else 100.0
    return {
        **cell.labels,
        "iterations": cfg.schedule.iterations,
        "wall_seconds": wall + (10.0 if cell.train_args else 0.0),
        "psnr": 20.0 + (0.5 if cfg.skips.static else 0.0),
        "ssim": 0.5,
        "psnr_moving": None if cell.labels["case"].startswith("still") else 12.0,
        "static_fraction": 0.0,
        "static_scene": False,
        "stopped_early_at": None,
    }


def test_each_variant_reaches_its_run_and_the_table_reports_both_sides(tmp_path, monkeypatch):
    calls = {}

    def fake(cells, out, options):
        for c in cells:
            calls[(c.labels["case"], c.labels["variant"])] = TrainConfig.from_dict(c.config), c
        return SweepResult(rows=[_fake_row(c) for c in cells])

    monkeypatch.setattr(skips, "run_sweep", fake)
    monkeypatch.setattr(skips, "simulate_cases", lambda cases, out: {c.name: out for c in cases})
    monkeypatch.setattr(skips, "render_table", lambda repeats: ["| render table |"])
    doc = tmp_path / "results.md"
    doc.write_text(
        "# Results\n\n## Skipping what a scene does not need\n\nold table\n\n## Next\n\nkept\n"
    )
    args = argparse.Namespace(
        iters=9,
        long_iters=30,
        repeats=1,
        out=tmp_path / "b",
        doc=doc,
        ray=None,
        max_retries=3,
        cpus_per_cell=1.0,
        jobs=1,
        fresh=False,
    )
    assert skips.run(args) == 0
    long = [name for name, v in skips.VARIANTS.items() if v.long]
    assert len(calls) == len(skips.CASES) * len(skips.VARIANTS) - len(long)
    # Long variants run on the static scene only, for --long-iters.
    assert {case for case, name in calls if name in long} == {"still-tiny-x1"}
    assert calls[("still-tiny-x1", "no-early-stop-long")][0].skips.early_stop is False
    assert calls[("still-tiny-x1", "no-mlp")][0].deform is False
    assert calls[("ball-tiny-x1", "coarse")][0].skips.coarse_fraction == 0.3
    assert calls[("ball-tiny-x1", "budget-3000")][0].densify.max_gaussians == 3000
    assert calls[("ball-tiny-x1", "no-depth-prior")][1].train_args == ("--depth-prior", "none")
    text = doc.read_text()
    assert "old table" not in text and text.count(skips.SECTION) == 1
    assert text.rstrip().endswith("## Next\n\nkept")
    # no MLP: 50 s against 100 s is half the time; in these fake runs the static skip adds 0.5 dB.
    assert (
        "| still | 9 / 50 / 20.50 / 0.500 | 9 / 100 / 20.00 / 0.500 | +50% | +0.50 dB | - / - |"
        in text
    )
    assert "| still | 30 / 100 / 20.50 / 0.500 | 30 / 100 / 20.50 / 0.500 |" in text
    assert "| render table |" in text
    line = next(x for x in text.splitlines() if x.startswith("| MLP for Gaussians") and "ball" in x)
    assert line.endswith("| +0% | +0.50 dB | 12.00 / 12.00 |")
    assert "9 iterations per run" in text


def test_a_missing_section_is_appended():
    assert (
        skips.replace_section("# R\n", [skips.SECTION, "", "t"]) == f"# R\n\n{skips.SECTION}\n\nt\n"
    )


def test_render_table_times_mono_against_colour_and_empty_tiles(monkeypatch):
    monkeypatch.setattr(skips, "RENDER_CASES", ((32, 40),))
    lines = skips.render_table(repeats=1)
    assert lines[0].startswith("| skipped |") and len(lines) == 4
    assert "monochrome" in lines[2] and "| 32x32, 40 |" in lines[2]
    # 32 px: 2x2 tiles; centred in 64x64 (4x4 tiles), 12 of 16 are empty.
    assert lines[3].startswith("| 12 empty of 16 tiles") and "| 64x64, 40 |" in lines[3]
    ms = [float(c) for c in lines[2].split("|")[3:5] + lines[3].split("|")[3:5]]
    assert all(v > 0 for v in ms)
