"""Docs that cannot rot: every shell command in the fenced code blocks of README.md and docs/
runs here, file by file in the order written, on a tiny scene and a short run where the docs
ask for a long one (MAPS). A command that cannot run in a test (external files, a server, a
run of minutes) is listed in SKIPS with the reason; a command in neither list simply runs, so a
new doc's commands are tested from the day it is written. Also: the bag that docs/make_bag.py
writes from a simulated dataset converts back to that dataset's own events and poses."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from evsplat.cli import main
from evsplat.data.event_files import read_events
from evsplat.data.poses import read_tum

ROOT = Path(__file__).resolve().parents[1]
MAKE_BAG = ROOT / "docs" / "make_bag.py"
# The first word of a line that starts a shell command in a fenced block.
COMMAND = re.compile(r"^(?:\w+=\S+\s+)*(?:evsplat|python|bash|mkdir|cat\s+>)\s")
# Dated records of past runs: their commands name the builds they ran against (placeholders such
# as OLD_PYTHON, other checkouts, a lent GPU machine), not today's tree.
RECORDS = ROOT / "docs" / "experiments"
# Commands that cannot run in the test suite, by pattern, with the reason.
SKIPS = {
    r"^bash scripts/demo\.sh": "installs packages (apt, uv, maturin) and trains for minutes; "
    "`evsplat demo`'s steps are the commands below it",
    r"^bash scripts/test\.sh": "runs this test suite",
    r"^bash scripts/(fetch_samples|davis_example)\.sh": "downloads the aedat sdist from the "
    "package registry (the DAVIS346 sample) and trains for minutes",
    r"^evsplat view\b": "serves the viewer until stopped (tests/test_viewer.py)",
    r"--ray\b": "needs a Ray cluster (tests/test_sweep_ray.py runs a local one)",
    r"^evsplat train-many 'recordings/\*'": "trains every recording a user has, 6000 iterations "
    "each",
    r"^evsplat bench paper\b": "29 training runs (tests/test_bench_paper.py runs a small grid)",
    r"^(OMP_NUM_THREADS=1 )?evsplat bench raster\b": "minutes of 512x512 renders "
    "(tests/test_raster.py checks the rasterizer)",
    r"^evsplat bench decode\b": "20 M events per format (tests/test_bench_decode.py runs it small)",
    r"^evsplat bench seeding\b": "a warm-up per scene and setting, minutes "
    "(tests/test_bench_seeding.py runs it on one scene)",
    r"^evsplat bench turn\b": "whole-sensor baselines at 1280x720, tens of seconds "
    "(tests/test_bench_turn.py runs it small)",
    r"--device cuda\b|^evsplat bench gpu\b": "needs a CUDA GPU",
    r"^evsplat simulate (?!.*--tiny)": "a full-size scene: minutes of simulation (`--tiny` runs)",
}
# Long runs made short: (pattern, replacement) on the command's text.
MAPS = [
    (re.compile(r"--iters \d+"), "--iters 6"),
    (re.compile(r"--times 0:1:0\.05\b"), "--times 0:1:0.25"),  # 5 frames, not 21
]


def fenced_commands(path: Path) -> list[str]:
    """The shell commands of a Markdown file's fenced blocks, in order: `\\` continuations and
    here-documents joined into one command, a trailing `# comment` kept (bash ignores it)."""
    commands, lines, inside = [], path.read_text().splitlines(), False
    i = 0
    while i < len(lines):
        text = lines[i].strip()
        i += 1
        if text.startswith("```"):
            inside = not inside
            continue
        if not inside or not COMMAND.match(text):
            continue
        command = text
        while command.endswith("\\") and i < len(lines):
            command = command[:-1] + " " + lines[i].strip()
            i += 1
        heredoc = re.search(r"<<'?(\w+)'?", command)
        if heredoc:
            body = []
            while i < len(lines) and lines[i].strip() != heredoc[1]:
                body.append(lines[i].strip())
                i += 1
            command = "\n".join([command, *body, heredoc[1]])
            i += 1
        commands.append(command)
    return commands


def planned(doc: Path) -> list[tuple[str, str | None]]:
    """Each command of ``doc`` with the reason it is skipped (None: it runs). A command that
    names what a skipped command writes (its ``--out``) is skipped too: its input is missing."""
    plan, missing = [], set()
    for command in fenced_commands(doc):
        why = next((why for pattern, why in SKIPS.items() if re.search(pattern, command)), None)
        words = shlex.split(command.split("\n")[0], comments=True)
        if why is None and missing & set(words):
            why = f"uses {', '.join(sorted(missing & set(words)))}, which a skipped command makes"
        if why is not None:
            missing.update(w for a, w in zip(words, words[1:]) if a == "--out")
        plan.append((command, why))
    return plan


DOCS = [ROOT / "README.md"] + sorted(
    p for p in (ROOT / "docs").rglob("*.md") if RECORDS not in p.parents
)
RUNNABLE = [d for d in DOCS if any(why is None for _, why in planned(d))]


def test_every_documented_command_is_run_or_skipped_with_a_reason():
    run = [c for d in DOCS for c, why in planned(d) if why is None]
    assert any(c.startswith("evsplat train ") for c in run), "the parser found no commands"
    assert {ROOT / "README.md", ROOT / "docs/real-data.md"} <= set(RUNNABLE)
    # The walkthrough's heredocs are parsed whole (the JSON is the file the command writes).
    readme = fenced_commands(ROOT / "README.md")
    assert any(c.startswith("cat > data/meta.json") and c.endswith("JSON") for c in readme)
    assert all(why for _, why in planned(ROOT / "README.md")[:2])  # scripts/demo.sh, test.sh


def _shell_tools(bin_dir: Path) -> dict[str, str]:
    """`evsplat` and `python` on PATH as this interpreter with this checkout's package."""
    bin_dir.mkdir()
    for name, target in (("evsplat", "-m evsplat.cli"), ("python", "")):
        tool = bin_dir / name
        tool.write_text(f'#!/bin/sh\nexec "{sys.executable}" {target} "$@"\n')
        tool.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "python"), env.get("PYTHONPATH", "")])
    return env


def _given(work: Path, commands: list[str], tiny_scene, env: dict[str, str]) -> None:
    """The files a doc's commands use without making them, in ``work``: the tiny ball as
    data/demo with a short run of it as runs/demo (the demo's), and recording.bag made from it
    by docs/make_bag.py (the user's recording)."""
    text = "\n".join(commands)
    ball = tiny_scene("ball")
    if "runs/demo" in text or "data/demo" in text:
        shutil.copytree(ball, work / "data" / "demo")
        run = ["train", str(work / "data/demo"), "--out", str(work / "runs/demo")]
        assert main([*run, "--preset", "tiny", "--iters", "6", "--no-progress"]) == 0
    if "recording.bag" in text and "make_bag.py" not in text:
        bag = [sys.executable, str(MAKE_BAG), str(ball), str(work / "recording.bag")]
        subprocess.run(bag, check=True, env=env)


@pytest.mark.parametrize("doc", RUNNABLE, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_documented_commands_run(doc, tiny_scene, tmp_path, monkeypatch):
    commands = [c for c, why in planned(doc) if why is None]
    env = _shell_tools(tmp_path / "bin")
    work = tmp_path / "work"
    work.mkdir()
    (work / "docs").symlink_to(ROOT / "docs")  # `python docs/make_bag.py` as from the root
    _given(work, commands, tiny_scene, env)
    for command in commands:
        for pattern, short in MAPS:
            command = pattern.sub(short, command)
        # A built-in scene's tiny variant is the session's copy (simulated once, seed 0).
        sim = re.fullmatch(r"evsplat simulate --scene (\w+) --tiny --out (\S+)(\s+#.*)?", command)
        if sim:
            shutil.rmtree(work / sim[2], ignore_errors=True)
            shutil.copytree(tiny_scene(sim[1]), work / sim[2])
            continue
        argv = shlex.split(command, comments=True)
        if argv[0] == "evsplat" and not set("|;&<>$`") & set(command.split("#")[0]):
            # In this process: the same entry point, without a torch import per command.
            monkeypatch.chdir(work)
            assert main(argv[1:]) == 0, f"{doc.relative_to(ROOT)}: `{command}` failed"
            continue
        done = subprocess.run(
            ["bash", "-ec", command], cwd=work, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, (
            f"{doc.relative_to(ROOT)}: `{command}` exited {done.returncode}:\n{done.stderr[-2000:]}"
        )


def test_make_bag_converts_back_to_the_simulated_events_and_poses(tiny_scene, tmp_path):
    sim = tiny_scene("ball")
    bag = tmp_path / "recording.bag"
    subprocess.run([sys.executable, str(MAKE_BAG), str(sim), str(bag)], check=True)
    out = tmp_path / "data"
    out.mkdir()
    argv = ["convert", str(bag), str(out / "events.h5"), "--poses", str(out / "poses.txt")]
    assert main(argv) == 0

    want, got = read_events(sim / "events.h5"), read_events(out / "events.h5")
    assert len(got) == len(want) > 0
    for k in "xyt":
        np.testing.assert_array_equal(getattr(got, k), getattr(want, k))
    np.testing.assert_array_equal(got.p > 0, want.p > 0)
    t_want, m_want = read_tum(sim / "poses.txt")
    t_got, m_got = read_tum(out / "poses.txt")
    np.testing.assert_array_equal(t_got, t_want)
    np.testing.assert_allclose(m_got, m_want, atol=1e-6)
