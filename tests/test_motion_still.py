"""Under a still camera, the scene's Gaussians in front of a moving object go behind it, and the
camera renders the scene exactly as before (oracle: the rasterizer itself, before and after)."""

from __future__ import annotations

import copy

import numpy as np
import torch

from evsplat.model.gaussians import GaussianModel
from evsplat.motion.still import behind_objects, is_still
from evsplat.projection import project
from evsplat.render import Renderer

W = H = 48
K = np.array([[40.0, 0.0, W / 2], [0.0, 40.0, H / 2], [0.0, 0.0, 1.0]])


def _scene() -> GaussianModel:
    model = GaussianModel.random_init(300, 1, [-1.2, -1.2, 1.0], [1.2, 1.2, 6.0], seed=4)
    with torch.no_grad():
        model.opacity_logits.fill_(0.0)
        model.sh.uniform_(-1.0, 1.0, generator=torch.Generator().manual_seed(5))
        model.log_scales.add_(
            torch.empty_like(model.log_scales).uniform_(-0.5, 0.5, generator=torch.Generator())
        )
    return model


def _render(model: GaussianModel, c2w: np.ndarray, rows: np.ndarray):
    """The view of the Gaussians ``rows`` (bool [N]) alone."""
    alone = copy.deepcopy(model)
    with torch.no_grad():
        alone.opacity_logits[torch.from_numpy(~rows)] = -30.0
    r = Renderer(alone, None, torch.from_numpy(K.astype(np.float32)), W, H, 0, 1_000_000)
    with torch.no_grad():
        return r.render(0, c2w)


def test_a_still_camera_sees_the_scene_unchanged_with_the_objects_unveiled():
    c2w = np.eye(4)
    c2w[:3, 3] = [0.1, -0.2, -0.5]
    model = _scene()
    back = 3.5  # the objects' farthest back
    with torch.no_grad():  # one nearer than the near plane: culled, and left so
        model.means[299] = torch.tensor([0.1, -0.2, -0.5 + 0.005])
    scene = np.ones(model.num_gaussians, dtype=bool)
    scene[:20] = False  # the objects' own Gaussians stay where they are
    _, z = project(model.means.detach().numpy().astype(np.float64), c2w, K)
    nearer = scene & (z < back)
    drawn = _render(model, c2w, np.ones_like(scene)).meta["radii"].numpy().reshape(-1) > 0
    assert not drawn[299]  # culled
    # Oracle: the rasterizer. What lies before the objects' back covers the image before, not after.
    assert _render(model, c2w, nearer).alpha.numpy().max() > 0.5
    before = [_render(model, c2w, rows).image.numpy() for rows in (nearer, ~nearer)]
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    moved = behind_objects(model, optimizer, scene, back, c2w, K, drawn)
    _, z2 = project(model.means.detach().numpy().astype(np.float64), c2w, K)
    assert moved == (nearer & drawn).sum() > 10
    assert _render(model, c2w, scene & (z2 < back)).alpha.numpy().max() < 1e-3
    went = nearer & drawn
    assert z2[went].min() >= back * (1 - 1e-6)
    assert (np.argsort(z2[went]) == np.argsort(z[went])).all()  # in their own order
    np.testing.assert_array_equal(z2[~went], z[~went])  # the culled and unseen stay
    # The still camera sees each part exactly as before: only the order of the two changed.
    for rows, old in zip((nearer, ~nearer), before):
        np.testing.assert_allclose(_render(model, c2w, rows).image.numpy(), old, atol=1e-4)
    assert optimizer.param_groups[0]["params"][0] is model.means  # the optimizer follows


def test_is_still_tells_a_still_camera_from_a_moving_one():
    still = np.repeat(np.eye(4)[None], 5, axis=0)
    assert is_still(still)
    moving = still.copy()
    moving[3, 0, 3] = 1e-3
    assert not is_still(moving)
