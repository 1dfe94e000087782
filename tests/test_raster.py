"""evsplat.rasterize against the dense torch reference (tests/reference/raster_ref.py):
forward values, gradients (autograd of the reference and finite differences), atomics paths,
means2d_grad, and input validation."""

from __future__ import annotations

import pytest
import torch

import evsplat
from evsplat.errors import EvsplatError
from evsplat.gpu import adapter_info
from tests.reference.raster_ref import ALPHA_MAX, ALPHA_MIN, POWER_CUT, T_MIN, project, render


def make_scene(n: int, d: int, width: int, height: int, seed: int = 0, depth: float = 4.0):
    """Random Gaussians in front of an identity camera looking down +z."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([1.0, 0.8, 0.5])
    means[:, 2] += depth
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.3 + 0.02
    opacities = torch.rand(n, generator=g) * 0.9 + 0.05
    features = torch.rand(n, d, generator=g)
    viewmat = torch.eye(4)
    f = 0.8 * width
    K = torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    return means, quats, scales, opacities, features, viewmat, K


def assert_forward_matches(scene, width, height, background=None):
    image, depth, alpha, meta = evsplat.rasterize(*scene, width, height, background=background)
    r_image, r_depth, r_alpha, r_meta = render(*scene, width, height, background=background)
    assert image.shape == r_image.shape and depth.shape == (height, width)
    assert (image - r_image).abs().max() <= 1e-4
    assert ((depth - r_depth).abs() <= 1e-4 * r_depth.abs().clamp(min=1.0)).all()
    assert ((alpha - r_alpha).abs() <= 1e-4 * r_alpha.abs().clamp(min=1.0)).all()
    assert torch.equal(meta["radii"], r_meta["radii"].to(torch.int32))
    assert torch.equal(meta["visible"], r_meta["visible"])
    vis = meta["visible"]
    assert torch.allclose(meta["means2d"][vis], r_meta["means2d"][vis], rtol=1e-5, atol=1e-3)
    assert torch.allclose(meta["depths"][vis], r_meta["depths"][vis], rtol=1e-6)
    return image, depth, alpha, meta


@pytest.mark.parametrize(
    "n,d,width,height",
    [(80, 3, 48, 32), (150, 1, 37, 53), (60, 8, 64, 64), (1, 3, 20, 20), (40, 16, 17, 33)],
)
def test_forward_matches_reference_on_random_scenes(n, d, width, height):
    scene = make_scene(n, d, width, height, seed=n + d)
    background = torch.rand(d, generator=torch.Generator().manual_seed(d))
    image, _, alpha, _ = assert_forward_matches(scene, width, height, background)
    assert alpha.max() > 0.05  # the scene really covers pixels


def test_forward_with_no_gaussians_is_the_background():
    scene = make_scene(0, 3, 16, 24)
    bg = torch.tensor([0.1, 0.2, 0.3])
    image, depth, alpha, meta = evsplat.rasterize(*scene, 16, 24, background=bg)
    assert torch.equal(image, bg.expand(24, 16, 3))
    assert not depth.any() and not alpha.any() and meta["radii"].numel() == 0


def test_forward_when_every_gaussian_is_culled_is_empty():
    means, *rest = make_scene(30, 3, 32, 32)
    behind = means.clone()
    behind[:, 2] = -3.0  # behind the camera
    image, depth, alpha, meta = evsplat.rasterize(behind, *rest, 32, 32)
    assert not image.any() and not depth.any() and not alpha.any()
    assert not meta["visible"].any() and not meta["radii"].any()
    assert_forward_matches((behind, *rest), 32, 32)


def test_gaussians_too_faint_to_draw_are_culled_in_projection_and_get_no_gradient():
    means, quats, scales, opacities, features, viewmat, K = make_scene(40, 3, 32, 32)
    faint = torch.arange(40) % 3 == 0
    opacities = torch.where(faint, torch.full_like(opacities, 0.9 / 255), opacities)
    scene = [means, quats, scales, opacities, features, viewmat, K]
    leaves = [p.clone().requires_grad_(True) for p in scene[:5]]
    image, depth, alpha, meta = evsplat.rasterize(*leaves, viewmat, K, 32, 32)
    assert not meta["visible"][faint].any() and not meta["radii"][faint].any()
    assert meta["visible"][~faint].any()
    assert_forward_matches(scene, 32, 32)
    # The image is what the others alone give (a faint one never passed the alpha test).
    kept = [p[~faint] for p in scene[:5]]
    alone = evsplat.rasterize(*kept, viewmat, K, 32, 32)[0]
    assert torch.allclose(image, alone, atol=1e-6)
    (image.sum() + depth.sum()).backward()
    for p in leaves:
        assert torch.isfinite(p.grad).all() and not p.grad[faint].any()


def test_intersection_capacity_follows_the_counts_without_losing_any():
    # The tile-key capacity grows on overflow (re-render) and shrinks after small renders; a
    # large render right after small ones must still composite every intersection.
    small = make_scene(3, 3, 32, 32, seed=1)
    means, quats, scales, *rest = make_scene(900, 3, 128, 128, seed=2)
    big = (means, quats, scales * 2.0, *rest)  # wide splats: tens of thousands of tile keys
    for scene, size in [(small, 32), (big, 128), (small, 32), (small, 32), (big, 128)]:
        *_, meta = assert_forward_matches(scene, size, size)
    # Tile pairs of the last render: enough that the capacity (1.5x the pairs) grew past 4 x 4096
    # (so the small renders shrank it back to 4096), so the last render overflowed the shrunk one.
    assert evsplat.rasterize(*big, 128, 128, count_work=True)[3]["work"]["pairs"] > 3 * 4096


def _square_pairs(meta: dict, width: int, height: int, tile: int) -> int:
    """Tile pairs of the 3-sigma bounding squares (the culling before the exact tile test)."""
    r = meta["radii"].float()[:, None]
    size = torch.tensor([(width + tile - 1) // tile, (height + tile - 1) // tile])
    lo = torch.minimum(((meta["means2d"] - r) / tile).floor().clamp(min=0), size)
    hi = torch.minimum(((meta["means2d"] + r) / tile).floor().add(1).clamp(min=0), size)
    return int((hi - lo).clamp(min=0).prod(dim=1)[meta["visible"]].sum())


def test_exact_tile_culling_drops_pairs_but_no_fragment_of_thin_faint_tilted_splats():
    # Needles and faint splats are where the ellipse-tile test and the opacity-aware extent cut
    # most of the 3-sigma square, and where a test that is not conservative would lose fragments.
    width, height = 96, 80
    means, quats, scales, opac, feats, view, K = make_scene(400, 3, width, height, seed=12)
    g = torch.Generator().manual_seed(12)
    scales = scales * torch.tensor([3.0, 0.05, 1.0]) * (0.3 + torch.rand(400, 1, generator=g))
    opac = torch.exp(torch.rand(400, generator=g) * -5.5).clamp(min=1 / 255)
    scene = (means, quats, scales, opac, feats, view, K)
    *_, meta = assert_forward_matches(scene, width, height)
    work = evsplat.rasterize(*scene, width, height, count_work=True)[3]["work"]
    assert work["pairs"] < 0.6 * _square_pairs(meta, width, height, work["tile_size"])


def test_forward_matches_reference_with_rotated_camera_and_off_centre_principal_point():
    means, quats, scales, opac, feats, _, _ = make_scene(120, 3, 40, 30, seed=7)
    angle = torch.tensor(0.3)
    c, s = torch.cos(angle), torch.sin(angle)
    viewmat = torch.eye(4)
    viewmat[:3, :3] = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    viewmat[:3, 3] = torch.tensor([0.2, -0.1, 0.5])
    K = torch.tensor([[30.0, 0.0, 12.0], [0.0, 34.0, 18.0], [0.0, 0.0, 1.0]])
    assert_forward_matches((means, quats, scales, opac, feats, viewmat, K), 40, 30)


def _grads(fn, scene, width, height, out_grads, double=False, **kw):
    leaves = [t.detach().clone() for t in scene[:5]]
    camera = list(scene[5:])
    if double:
        leaves = [t.double() for t in leaves]
        camera = [t.double() for t in camera]
    for t in leaves:
        t.requires_grad_(True)
    image, depth, alpha, meta = fn(*leaves, *camera, width, height, **kw)
    g_img, g_depth, g_alpha = out_grads
    loss = (image * g_img.to(image.dtype)).sum() + (depth * g_depth.to(depth.dtype)).sum()
    loss = loss + (alpha * g_alpha.to(alpha.dtype)).sum()
    loss.backward()
    return [t.grad.float() for t in leaves], meta


def _out_grads(width, height, d, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (
        torch.randn(height, width, d, generator=g),
        torch.randn(height, width, generator=g),
        torch.randn(height, width, generator=g),
    )


def relative_errors(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """|a - b| relative to |b|, floored at 1e-3 of the largest |b| (tiny entries are noise)."""
    return (a - b).abs() / (b.abs() + 1e-3 * b.abs().max().clamp(min=1e-12))


NAMES = ["means", "quats", "scales", "opacities", "features"]


@pytest.mark.parametrize("d", [1, 3, 8])
def test_gradients_match_reference_autograd(d):
    width, height = 40, 28
    scene = make_scene(70, d, width, height, seed=10 + d)
    out = _out_grads(width, height, d, seed=d)
    gpu, meta = _grads(evsplat.rasterize, scene, width, height, out)
    ref, _ = _grads(render, scene, width, height, out, double=True)
    for name, a, b in zip(NAMES, gpu, ref):
        rel = relative_errors(a, b)
        assert rel.median() <= 1e-3, (name, rel.median())
        # Every entry within 1% of itself, or within 5e-5 of the largest: an entry far below the
        # largest is a sum of per-pixel terms that cancel, and float32 atomics add those terms in
        # the device's order (an NVIDIA H200 left 1.9e-5 of the largest on one such opacity
        # gradient, lavapipe 0.9e-5; the float32 torch reference 0.15e-5).
        bound = 1e-2 * b.abs() + 5e-5 * b.abs().max()
        assert ((a - b).abs() <= bound).all(), (name, ((a - b).abs() / bound).max())


def test_means2d_grad_is_filled_with_screen_space_gradient():
    width, height = 32, 32
    scene = make_scene(40, 3, width, height, seed=3)
    means = scene[0].clone().requires_grad_(True)
    image, _, _, meta = evsplat.rasterize(means, *scene[1:], width, height)
    assert not meta["means2d_grad"].any()
    image.sum().backward()
    g2d = meta["means2d_grad"]
    vis = meta["visible"]
    assert g2d[vis].abs().sum() > 0 and not g2d[~vis].any()
    # The reference's gradient with respect to its own projected means is the oracle.
    ref_means = scene[0].clone().double().requires_grad_(True)
    r_img, _, _, r_meta = render(ref_means, *[t.double() for t in scene[1:]], width, height)
    r_meta["means2d"].retain_grad()
    r_img.sum().backward()
    ref2d = r_meta["means2d"].grad.float()
    assert torch.allclose(g2d[vis], ref2d[vis], rtol=1e-3, atol=1e-3 * ref2d.abs().max())


def test_gradients_match_finite_differences_of_float64_reference():
    width, height = 12, 10
    scene = make_scene(4, 2, width, height, seed=5, depth=3.0)
    scene[3][:] = 0.6  # keep alpha away from the 0.99 clamp
    out = _out_grads(width, height, 2, seed=9)
    gpu, _ = _grads(evsplat.rasterize, scene, width, height, out)

    def loss(params):
        image, depth, alpha, _ = render(*params, *[t.double() for t in scene[5:]], width, height)
        total = (image * out[0].double()).sum() + (depth * out[1].double()).sum()
        return total + (alpha * out[2].double()).sum()

    base = [t.double() for t in scene[:5]]
    eps = 1e-6
    for k, name in enumerate(NAMES):
        fd = torch.zeros_like(base[k])
        flat = fd.view(-1)
        for j in range(flat.numel()):
            plus = [t.clone() for t in base]
            minus = [t.clone() for t in base]
            plus[k].view(-1)[j] += eps
            minus[k].view(-1)[j] -= eps
            flat[j] = (loss(plus) - loss(minus)) / (2 * eps)
        rel = relative_errors(gpu[k], fd.float())
        assert rel.max() <= 1e-2, (name, rel.max())


def _reference_fragments(scene, width: int, height: int) -> int:
    """Pixel-Gaussian fragments the float64 reference composites (3DGS's rules, depth order)."""
    means, quats, scales, opac, feats, viewmat, K = [t.double() for t in scene]
    mean2d, conic, z, _, ok = project(means, quats, scales, opac, viewmat, K, width, height,
                                      0.01, 1e4)  # fmt: skip
    order = torch.argsort(torch.where(ok, z, torch.full_like(z, float("inf"))), stable=True)
    order = order[ok[order]]
    jj, ii = torch.meshgrid(torch.arange(width), torch.arange(height), indexing="xy")
    pix = torch.stack([jj.reshape(-1) + 0.5, ii.reshape(-1) + 0.5], -1).double()
    dd = mean2d[order][None] - pix[:, None]
    co = conic[order]
    power = -0.5 * (co[:, 0] * dd[..., 0] ** 2 + co[:, 2] * dd[..., 1] ** 2)
    power = power - co[:, 1] * dd[..., 0] * dd[..., 1]
    alpha = torch.clamp(opac[order][None] * torch.exp(power.clamp(max=0.0)), max=ALPHA_MAX)
    use = (power >= POWER_CUT) & (alpha >= ALPHA_MIN)
    t_after = torch.cumprod(1 - torch.where(use, alpha, torch.zeros_like(alpha)), dim=1)
    return int((use & (t_after >= T_MIN)).sum())


def test_work_counts_match_the_reference_fragments_and_leave_the_image_unchanged():
    width, height = 48, 40
    scene = make_scene(300, 3, width, height, seed=8)
    plain = evsplat.rasterize(*scene, width, height)
    image, depth, alpha, meta = evsplat.rasterize(*scene, width, height, count_work=True)
    assert torch.equal(image, plain[0]) and torch.equal(alpha, plain[2])
    work = meta["work"]
    # Composited steps are the reference's fragments (float32 vs float64: a few may sit on the
    # alpha or transmittance thresholds).
    fragments = _reference_fragments(scene, width, height)
    assert abs(work["contributed"] - fragments) <= 2 + 1e-3 * fragments
    # Every step is one of a tile list's entries at one of the tile's pixels.
    assert work["contributed"] <= work["evaluated"]
    assert work["evaluated"] + work["saturated"] <= work["pairs"] * work["tile_size"] ** 2
    assert work["saturated"] > 0  # the scene saturates pixels (alpha reaches 1 - 1e-4)


def test_float_atomic_and_cas_paths_agree():
    width, height = 48, 40
    scene = make_scene(300, 4, width, height, seed=21)
    out = _out_grads(width, height, 4, seed=2)
    caps = adapter_info()
    modes = ["cas", "float"] if caps["float32_atomics"] else ["cas"]
    results = [_grads(evsplat.rasterize, scene, width, height, out, atomics=m)[0] for m in modes]
    ref, _ = _grads(render, scene, width, height, out, double=True)
    for grads in results:
        for name, a, b in zip(NAMES, grads, ref):
            assert relative_errors(a, b).median() <= 1e-3, name
    for name, a, b in zip(NAMES, results[0], results[-1]):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-5 * b.abs().max()), name


def test_cas_path_is_selected_by_environment_variable(monkeypatch):
    width, height = 24, 24
    scene = make_scene(50, 3, width, height, seed=4)
    out = _out_grads(width, height, 3)
    plain, _ = _grads(evsplat.rasterize, scene, width, height, out)
    monkeypatch.setenv("EVSPLAT_ATOMICS", "cas")
    cas, _ = _grads(evsplat.rasterize, scene, width, height, out)
    for a, b in zip(plain, cas):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-6 + 1e-5 * b.abs().max())


@pytest.mark.parametrize("atomics", ["float", "cas"])
def test_subgroup_sums_and_per_invocation_atomics_agree(monkeypatch, atomics):
    # The backward pass sums gradients across subgroups before its atomics where the adapter has
    # subgroup operations (lavapipe has); EVSPLAT_SUBGROUPS=off makes each invocation add its own.
    if atomics == "float" and not adapter_info()["float32_atomics"]:
        pytest.skip("the adapter has no float32 atomics")
    width, height = 48, 40
    scene = make_scene(300, 5, width, height, seed=22)
    out = _out_grads(width, height, 5, seed=3)
    summed, _ = _grads(evsplat.rasterize, scene, width, height, out, atomics=atomics)
    monkeypatch.setenv("EVSPLAT_SUBGROUPS", "off")
    solo, _ = _grads(evsplat.rasterize, scene, width, height, out, atomics=atomics)
    ref, _ = _grads(render, scene, width, height, out, double=True)
    for name, a, b, r in zip(NAMES, summed, solo, ref):
        assert relative_errors(a, r).median() <= 1e-3, name
        assert relative_errors(b, r).median() <= 1e-3, name
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-5 * b.abs().max()), name


def _render_and_grads(scene, width, height, d):
    image, depth, alpha, meta = evsplat.rasterize(*scene, width, height, count_work=True)
    grads, _ = _grads(evsplat.rasterize, scene, width, height, _out_grads(width, height, d, seed=1))
    return (image, depth, alpha), meta["work"], grads


@pytest.mark.parametrize("case", ["pixels", "tile pairs"])
def test_renders_over_a_forced_binding_limit_are_the_same_in_bands(monkeypatch, case):
    # EVSPLAT_MAX_BINDING caps the storage-binding size the rasterizer plans with (lavapipe's is
    # 128 MiB). Over it, the image is rendered in bands of tile rows: per-pixel buffers split by
    # rows up front, a band whose tile pairs overflow split in halves and rendered again.
    limit = 16384
    if case == "pixels":  # 64 x 60 x (3 + 2) floats of output gradients: 75 KiB
        width, height, d = 64, 60, 3
        means, quats, scales, opac, *rest = make_scene(200, d, width, height, seed=5)
        scene = (means, quats, scales * 1.5, opac, *rest)
    else:  # a narrow image whose rows fit, under Gaussians covering it: 4798 pairs, 19 KiB
        width, height, d = 16, 64, 1
        means, quats, scales, opac, *rest = make_scene(300, d, width, height, seed=5)
        scene = (means * 0.05, quats, scales * 6.0, opac, *rest)
    whole, work, grads = _render_and_grads(scene, width, height, d)
    monkeypatch.setenv("EVSPLAT_MAX_BINDING", str(limit))
    banded, banded_work, banded_grads = _render_and_grads(scene, width, height, d)
    if case == "pixels":
        assert 4 * width * height * (d + 2) > 4 * limit
    else:
        assert 4 * work["pairs"] > limit and 4 * width * height * 4 <= limit
    for a, b in zip(whole, banded):
        assert torch.equal(a, b)  # the same pixels, bit for bit
    assert work == banded_work
    for name, a, b in zip(NAMES, banded_grads, grads):
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-6 * b.abs().max()), name


def test_a_render_that_cannot_fit_the_binding_limit_names_the_buffer(monkeypatch):
    scene = make_scene(400, 3, 32, 32, seed=6)  # 400 Gaussians x 14 inputs: 22 KiB
    monkeypatch.setenv("EVSPLAT_MAX_BINDING", "16384")
    with pytest.raises(EvsplatError, match="inputs buffer needs .* storage binding limit"):
        evsplat.rasterize(*scene, 32, 32)


def test_interleaved_renders_each_get_their_own_gradients():
    # More renders in flight than the extension keeps states for (3), with different channel
    # counts, differentiated in reverse order: kept states are reused, evicted ones re-rendered.
    width, height = 32, 24
    channels = [3, 5, 1, 3, 8]
    scenes = [make_scene(60, d, width, height, seed=10 + i) for i, d in enumerate(channels)]
    leaves = [[t.clone().requires_grad_(True) for t in sc[:5]] for sc in scenes]
    images = [evsplat.rasterize(*lv, *sc[5:], width, height)[0] for lv, sc in zip(leaves, scenes)]
    for img in reversed(images):
        img.sum().backward()
    for d, sc, lv in zip(channels, scenes, leaves):
        zeros = torch.zeros(height, width)
        ref, _ = _grads(
            render, sc, width, height, (torch.ones(height, width, d), zeros, zeros), double=True
        )
        for name, t, b in zip(NAMES, lv, ref):
            assert relative_errors(t.grad, b).median() <= 1e-3, (d, name)


@pytest.mark.parametrize("later", [1, 4])
def test_a_render_made_before_its_backward_leaves_the_gradients_exact(later):
    # L_e renders two or three views and differentiates them all: a render's gradients must not
    # depend on renders made after its forward (1: its state is kept; 4: it is evicted and
    # rendered again). A DAVIS346 frame with 1,500 Gaussians: at this size the kept and the
    # re-rendered backward both gave wrong gradients (relative error 0.9; at 96x96 they did
    # not). The image is linear in the features, so their central differences are exact.
    width, height = 346, 260
    scene = make_scene(1500, 1, width, height, seed=3)
    weights = torch.randn(height, width, 1, generator=torch.Generator().manual_seed(4))
    leaves = [t.clone().requires_grad_(True) for t in scene[:5]]

    def loss(parts, between: int = 0) -> torch.Tensor:
        image = evsplat.rasterize(*parts, *scene[5:], width, height)[0]
        with torch.no_grad():
            for _ in range(between):
                evsplat.rasterize(*scene, width, height)
        return (image * weights).sum()

    loss(leaves).backward()
    alone = [t.grad.clone() for t in leaves]
    for t in leaves:
        t.grad = None
    loss(leaves, later).backward()
    for name, t, a in zip(NAMES, leaves, alone):
        assert relative_errors(t.grad, a).max() <= 1e-4, name
    step = torch.randn(1500, 1, generator=torch.Generator().manual_seed(5))
    with torch.no_grad():
        up, down = (loss([*scene[:4], scene[4] + s * step]) for s in (1.0, -1.0))
    exact = float(up - down) / 2
    assert abs(float((leaves[4].grad * step).sum()) - exact) <= 1e-3 * abs(exact) + 1e-2


@pytest.mark.parametrize(
    "argument,value",
    [
        ("means", float("nan")),
        ("quats", float("inf")),
        ("scales", float("-inf")),
        ("opacities", float("nan")),
        ("features", float("inf")),
        ("viewmat", float("nan")),
        ("K", float("inf")),
    ],  # fmt: skip
)
def test_non_finite_input_raises_error_naming_the_argument(argument, value):
    scene = dict(zip(["means", "quats", "scales", "opacities", "features", "viewmat", "K"],
                     make_scene(5, 3, 16, 16)))  # fmt: skip
    bad = scene[argument].clone()
    bad.view(-1)[0] = value
    scene[argument] = bad
    with pytest.raises(EvsplatError, match=f"{argument} contains NaN or Inf"):
        evsplat.rasterize(**scene, width=16, height=16)


def test_wrong_shapes_and_dtypes_raise_clear_errors():
    means, quats, scales, opac, feats, view, K = make_scene(5, 3, 16, 16)
    with pytest.raises(EvsplatError, match=r"quats has shape \[5, 3\], expected \[5, 4\]"):
        evsplat.rasterize(means, quats[:, :3], scales, opac, feats, view, K, 16, 16)
    with pytest.raises(EvsplatError, match="means must be float32"):
        evsplat.rasterize(means.double(), quats, scales, opac, feats, view, K, 16, 16)
    with pytest.raises(EvsplatError, match="features have 33 channels"):
        evsplat.rasterize(means, quats, scales, opac, torch.rand(5, 33), view, K, 16, 16)
    with pytest.raises(EvsplatError, match="near"):
        evsplat.rasterize(means, quats, scales, opac, feats, view, K, 16, 16, near=0.0)
    with pytest.raises(EvsplatError, match="width"):
        evsplat.rasterize(means, quats, scales, opac, feats, view, K, 0, 16)
