"""Oracle experiment (issue 'learned motion'): Gaussians start on the ball at its true place.

The simulator knows the scene: the ball's surface and the room are back-projected from its
ground-truth render at the first time, with their true colours, and training then has to move
the ball's Gaussians along the ball's true path through the deformation MLP alone (time-local
opacity off). If the tracking error does not fall, the losses or their gradients cannot carry
motion, whatever the initialisation. The background is marked static (it skips the MLP) so the
test isolates the ball; the sequence is cut to its first 60 ms, where the ball moves ~30 px
(the gradients of L_e reach that far only from a nearby start: docs/experiments/motion.md, "Can
the losses carry motion?").
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from evsplat.config import preset
from evsplat.data.dataset import load_dataset
from evsplat.model.deform import deformed
from evsplat.model.gaussians import SH_C0
from evsplat.projection import project_points, viewmat
from evsplat.scenes import get_scene
from evsplat.train.loop import Trainer

HORIZON_US = 60_000
ITERATIONS = 200
# Training seeds of the test, split between two children that run at once.
SEEDS = 12


def _back_project(scene, t_us: int, K: np.ndarray, moving: bool):
    """World points, colours and depths of the pixels on (or off) the moving object."""
    rgb, depth, mask = scene.render(t_us)
    ys, xs = np.nonzero((mask if moving else ~mask) & (depth > 0))
    z = depth[ys, xs].astype(np.float64)
    rays = np.stack(
        [(xs + 0.5 - K[0, 2]) / K[0, 0], (ys + 0.5 - K[1, 2]) / K[1, 1], np.ones_like(z)], 1
    )
    c2w = scene.c2w(t_us)
    points = (rays * z[:, None]) @ c2w[:3, :3].T + c2w[:3, 3]
    return points, rgb[ys, xs], z


def _tracking_error(trainer: Trainer, scene, n_ball: int, times: np.ndarray) -> float:
    """Median pixel distance between the ball Gaussians' median position (offset to the true
    centre at the first time) and the true centre, over ``times``. The median, not the mean: a
    few Gaussians that no loss holds (transparent, or behind the ball) may drift anywhere."""
    K = trainer.renderer.K
    centre = lambda t: scene.primitives[-1].pose(t * 1e-6)[:3, 3]  # noqa: E731
    errors = []
    with torch.no_grad():
        first = deformed(trainer.model, trainer.mlp, 0.0)[0][:n_ball].median(0).values
        offset = first.double().numpy() - centre(times[0])
        for t in times:
            mean = deformed(trainer.model, trainer.mlp, trainer.renderer.time(t))[0][:n_ball]
            pred = mean.median(0).values.double().numpy() - offset
            w2c = viewmat(scene.c2w(int(t)))
            both = torch.tensor(np.stack([pred, centre(t)]), dtype=torch.float32)
            uv = project_points(both, w2c, K)
            errors.append(float((uv[0] - uv[1]).norm()))
    return float(np.median(errors))


def oracle_errors(data_dir: str, run_dir: str, seed: int = 0) -> tuple[float, list[float]]:
    """The ball Gaussians' tracking error before training and at the second half's
    checkpoints, training with ``seed`` (run in a child process by the test)."""
    torch.set_num_threads(1)
    # One ray per pixel: each back-projected point carries its own surface's colour, not the
    # pixel's mix of ball and wall at the ball's rim (with that mix, the ball's rim and the wall
    # beside it start with each other's colours and the ball stays put: 15.0 -> 16.4 px).
    data, scene = load_dataset(Path(data_dir)), get_scene("ball", tiny=True, samples=1)
    data = dataclasses.replace(data, t_end_us=data.t_start_us + HORIZON_US)
    K = data.K
    on_ball = _back_project(scene, data.t_start_us, K, moving=True)
    room = [_back_project(scene, t, K, moving=False) for t in (0, HORIZON_US)]
    rng = np.random.default_rng(0)
    room_pts = np.concatenate([r[0] for r in room])
    keep = rng.choice(len(room_pts), size=3000, replace=False)
    parts = [on_ball] + [tuple(np.concatenate([r[k] for r in room])[keep] for k in range(3))]
    points, colours, depth = (np.concatenate([p[k] for p in parts]) for k in range(3))
    n_ball = len(on_ball[0])

    cfg = preset("tiny")
    cfg.seed = seed
    cfg.schedule.iterations = ITERATIONS
    cfg.schedule.warmup_fraction = 0.0
    cfg.schedule.grad_norms_every = 0
    cfg.model.temporal_opacity = False
    cfg.model.mlp_lr = 5e-3
    # The rate held near its start (a decay over 200 runs, as the fixed 40k-iteration horizon
    # gave before 30a96a3): the test asks whether the losses carry motion, and 200
    # iterations with the training's own decay (over 4/3 of the run) leave the MLP too small a
    # rate to move 30 px.
    cfg.model.mlp_lr_span = 200.0
    cfg.model.pe_x = 3
    # L_ef is off: with it the ball drifts off its path even here (docs/experiments/motion.md, "Can
    # the losses carry motion?").
    cfg.loss.w_flow = 0.0
    cfg.densify.start_fraction = 2.0  # no densification: rows stay the ball's
    cfg.skips.static = False
    cfg.skips.early_stop = False
    cfg.num_gaussians = len(points)
    trainer = Trainer(data, cfg, Path(run_dir))
    model = trainer.model
    with torch.no_grad():
        model.means.copy_(torch.from_numpy(points.astype(np.float32)))
        model.sh[:, 0, :] = torch.from_numpy(((colours - 0.5) / SH_C0).astype(np.float32))
        size = np.log(depth / K[0, 0]).astype(np.float32)
        model.log_scales.copy_(torch.from_numpy(size)[:, None].expand(-1, 3))
        model.opacity_logits.fill_(math.log(0.8 / 0.2))
    static = torch.ones(len(points), dtype=torch.bool)
    static[:n_ball] = False
    trainer.renderer.static_mask = static

    times = np.linspace(data.t_start_us, data.t_end_us, 13).astype(np.int64)
    before = _tracking_error(trainer, scene, n_ball, times)
    late = []
    for it in range(ITERATIONS):
        trainer.step(it)
        if it + 1 >= ITERATIONS // 2 and (it + 1) % 25 == 0:
            late.append(_tracking_error(trainer, scene, n_ball, times))
    return before, late


def test_training_moves_oracle_gaussians_along_the_true_path(tiny_scene, tmp_path):
    # Child processes with one lavapipe thread each: the backward's float atomics then add in a
    # fixed order and each run is reproducible (with several threads a loaded machine saw the error
    # end at 9.4-10.9 px against 3.0-5.1 px in quiet runs). The training is chaotic at this rate:
    # one run is one trajectory, and about a quarter of them throw or stall the ball, which seed
    # does so moving with the order in which the backward pass adds its float sums
    # (docs/experiments/rasterizer.md, "Two quads per invocation": three builds that differ only in
    # that order, 24 seeds each, halve the error in 14-18 seeds; with four seeds each passed or
    # failed by that order). So the bar is on twelve seeds, two at a time: their median error and
    # how many fall. Each child trains its six seeds one after another: a seed's numbers are the
    # same as in a process of its own (seeds 0 and 1 in one child, 1 alone: equal to the last
    # bit), and a child's start (importing torch, ~20 s on 2 cores) is paid twice, not 12 times.
    code = (
        "import json, sys; sys.path.insert(0, sys.argv[1]); "
        "from test_train_oracle_motion import oracle_errors; "
        "print(json.dumps([oracle_errors(sys.argv[2], f'{sys.argv[3]}/run{s}', s) "
        "for s in range(int(sys.argv[4]), int(sys.argv[5]), 2)]))"
    )
    env = {**os.environ, "LP_NUM_THREADS": "1", "EVSPLAT_QUIET": "1"}
    here, data = str(Path(__file__).parent), str(tiny_scene("ball"))
    children = [
        subprocess.Popen(
            [sys.executable, "-c", code, here, data, str(tmp_path), str(first), str(SEEDS)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for first in (0, 1)
    ]
    per_child = []
    for child in children:
        out, err = child.communicate()
        assert child.returncode == 0, err[-2000:]
        per_child.append(json.loads(out.strip().splitlines()[-1]))
    results = [r for pair in zip(*per_child) for r in pair]  # seeds 0, 1, 2, ...
    # The MLP's rate barely decays (above), so the error jitters between checkpoints (1-9 px):
    # the median over the second half's checkpoints is each run's statistic. Measured: 15.0 px
    # before; after, over seeds 0-11, a median of 3.2 / 3.5 / 5.5 px with 12 / 11 / 10 seeds
    # below 15.0 (the three builds above), over seeds 12-23 4.3 / 8.0 / 3.2 px with 11 / 11 / 10.
    before = [b for b, _ in results]
    after = [float(np.median(late)) for _, late in results]
    assert min(before) > 10.0
    report = f"tracking error {before[0]:.2f} -> {[round(a, 2) for a in after]} px"
    assert float(np.median(after)) < 0.6 * before[0], report
    assert sum(a < b for a, b in zip(after, before)) >= 9, report
