"""Per-object rigid motion: a Gaussian of object k (``object_id`` k >= 0) at canonical x sits at
``R_k(t) (x - c_k) + c_k + T_k(t)`` at normalised time t, turned by R_k(t) too, ``c_k`` being its
centre at its reference time (R = I, T = 0). R_k (rotation vectors) and T_k are linear between
shared knots, started from the seeding; the MLP adds what is not rigid. The scene's Gaussians
(id -1) are not moved here."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from evsplat.model.gaussians import quat_to_rotmat

ANGLE_EPS = 1e-6  # below this angle (rad) the half-angle terms take their Taylor forms
#: Object radii a knot's translation may move from its seeded place at no cost: about the
#: seeding's error, well short of a pull the prior must stop (docs/motion.md, "Tuning numbers").
FREE = 0.25
DIST_EPS = 1e-12  # keeps the distance's gradient finite where a knot is at its seeded place
#: How far behind an object (radii) the warm-up's smear of it reaches along the rays: where the
#: seeding takes it (``motion.seed.smear``) and, under a still camera, where it is pruned later
#: (``swept``).
BEHIND = 2.0
SWEPT_ROWS = 16_384  # rows per batch in ``swept``: [rows, segments, 3] stays tens of MB


def knot_times_us(t_start_us: int, t_end_us: int, knots: int) -> np.ndarray:
    """float64 [G]: the times (µs) of ``knots`` knots spread evenly over the sequence, where
    ``ObjectMotion.at`` reads them (normalised time 0 to 1)."""
    return np.linspace(t_start_us, t_end_us, knots)


def rotvec_to_quat(v: Tensor) -> Tensor:
    """Unit quaternions [...,4] (w, x, y, z) of rotation vectors [...,3], gradients finite at 0."""
    theta2 = (v * v).sum(-1, keepdim=True)
    small = theta2 < ANGLE_EPS**2
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    w = torch.where(small, 1.0 - theta2 / 8.0, torch.cos(theta / 2))
    k = torch.where(small, 0.5 - theta2 / 48.0, torch.sin(theta / 2) / theta)
    return torch.cat([w, k * v], -1)


def quat_multiply(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton products a ⊗ b of quaternions [...,4] (w, x, y, z)."""
    aw, av, bw, bv = a[..., :1], a[..., 1:], b[..., :1], b[..., 1:]
    w = aw * bw - (av * bv).sum(-1, keepdim=True)
    return torch.cat([w, aw * bv + bw * av + torch.linalg.cross(av, bv, dim=-1)], -1)


class ObjectMotion(nn.Module):
    """K objects' rigid paths on G shared knots over normalised time [0, 1]: ``centres`` [K,3]
    (world, at the reference time), ``radii`` [K] (world, the track prior's length scale), and
    ``translations``, ``rotvecs`` [K,G,3] (parameters), their starting values ``prior_*``;
    ``behind``: how far behind them (radii) the space they hide is ``swept``."""

    def __init__(
        self,
        centres: Tensor,
        radii: Tensor,
        translations: Tensor,
        rotvecs: Tensor,
        spans: Tensor | None = None,
        fade: float = 0.0,
        behind: float = 0.0,
    ):
        super().__init__()
        k, g = translations.shape[:2]
        if centres.shape != (k, 3) or radii.shape != (k,) or rotvecs.shape != (k, g, 3) or g < 2:
            got = [tuple(x.shape) for x in (centres, radii, translations, rotvecs)]
            need = "centres [K,3], radii [K], translations and rotvecs [K,G,3], G >= 2"
            raise ValueError(f"ObjectMotion: shapes {got}; need {need}")
        self.register_buffer("centres", centres.float().clone())
        self.register_buffer("radii", radii.float().clone())
        # [K,2] normalised times each object is in view between, faded over ``fade``; ±inf: always.
        inf = float("inf")
        spans = torch.tensor([[-inf, inf]] * k) if spans is None else spans.float().clone()
        self.register_buffer("spans", spans)
        self.register_buffer("fade", torch.tensor(float(fade)))
        self.register_buffer("behind", torch.tensor(float(behind)))
        self.translations = nn.Parameter(translations.float().clone())
        self.rotvecs = nn.Parameter(rotvecs.float().clone())
        self.register_buffer("prior_translations", translations.float().clone())
        self.register_buffer("prior_rotvecs", rotvecs.float().clone())

    def at(self, t: float) -> tuple[Tensor, Tensor]:
        """(unit quaternions [K,4], translations [K,3]) at normalised time ``t`` (clamped)."""
        g = self.translations.shape[1]  # knots
        u = min(max(float(t), 0.0), 1.0) * (g - 1)
        i = min(int(u), g - 2)
        w = u - i
        trans = (1.0 - w) * self.translations[:, i] + w * self.translations[:, i + 1]
        rotvec = (1.0 - w) * self.rotvecs[:, i] + w * self.rotvecs[:, i + 1]
        return rotvec_to_quat(rotvec), trans

    def apply(
        self, means: Tensor, quats: Tensor, object_id: Tensor, t: float
    ) -> tuple[Tensor, Tensor]:
        """(means [N,3], unit quaternions [N,4]) with each object's Gaussians moved rigidly to
        ``t``; rows with ``object_id`` -1 are returned as they are."""
        turn, trans = self.at(t)
        rows = torch.nonzero(object_id >= 0).reshape(-1)
        if rows.numel() == 0:
            return means, quats
        k = object_id[rows]
        c = self.centres[k]
        moved = torch.einsum("nij,nj->ni", quat_to_rotmat(turn)[k], means[rows] - c) + c + trans[k]
        turned = quat_multiply(turn[k], quats[rows])
        return means.index_copy(0, rows, moved), quats.index_copy(0, rows, turned)

    def visibility(self, object_id: Tensor, t: float) -> Tensor:
        """[N] opacity factor at normalised time ``t``: 1 for the scene and for an object in
        view, falling smoothly to 0 over ``fade`` outside its span."""
        width = float(self.fade.clamp_min(1e-6))
        start, end = self.spans[:, 0], self.spans[:, 1]
        seen = torch.sigmoid((t - start) / width * 4) * torch.sigmoid((end - t) / width * 4)
        out = torch.ones(object_id.shape[0], dtype=seen.dtype, device=seen.device)
        rows = object_id >= 0
        out[rows] = seen[object_id[rows]]
        return out

    @torch.no_grad()
    def swept(self, means: Tensor, object_id: Tensor, eyes: Tensor) -> Tensor:
        """[N] bool: the scene's rows (``object_id`` -1) whose centre ``means`` [N,3] lies in
        the space an object passes through while in view (within its radius of its path) or
        hides from the camera (within its radius of the ray from the camera's centre at each
        knot, ``eyes`` [G,3], through its centre, from there to ``behind`` radii behind it) or
        would hide it (the cone from the camera's centre there to its disc): the warm-up spreads
        an object's events there as static Gaussians, which, left, draw a trail along its path."""
        knots = torch.linspace(0.0, 1.0, self.translations.shape[1], device=means.device)
        out = torch.zeros(means.shape[0], dtype=torch.bool, device=means.device)
        for centre, radius, trans, (start, end) in zip(
            self.centres, self.radii, self.translations.detach(), self.spans
        ):
            path = centre + trans  # [G,3]
            ray = path - eyes
            ray = ray / ray.norm(dim=-1, keepdim=True).clamp_min(DIST_EPS)
            back = path + self.behind * radius * ray
            seen = (knots >= start) & (knots <= end)
            pair = seen[:-1] & seen[1:]  # the path between two knots in view
            eye = eyes[seen]
            a = torch.cat([path[:-1][pair], path[seen], eye])  # [S,3] segments from a to a + ab
            ab = torch.cat([path[1:][pair], back[seen], path[seen]]) - a
            if a.shape[0] == 0:
                continue
            # Tubes of the radius about the path and the rays behind, cones from the eyes.
            tube = torch.arange(a.shape[0], device=a.device) < a.shape[0] - eye.shape[0]
            # Only rows in the segments' bounding box grown by the radius can be that near.
            lo, hi = torch.minimum(a, a + ab).amin(0), torch.maximum(a, a + ab).amax(0)
            box = ((means > lo - radius) & (means < hi + radius)).all(1) & (object_id < 0)
            for rows in torch.nonzero(box).reshape(-1).split(SWEPT_ROWS):
                x = means[rows, None] - a  # [R,S,3]
                along = ((x * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(DIST_EPS)).clamp(0.0, 1.0)
                reach = torch.where(tube, radius, radius * along)
                out[rows] |= ((x - along[..., None] * ab).norm(dim=-1) < reach).any(1)
        return out

    def prior_loss(self) -> Tensor:
        """Squared distance of the paths from their starting values, averaged over the objects:
        translations in object radii beyond ``FREE`` of them summed over the knots (a mean lets
        one knot stray), rotations in radians averaged over the knots (held per knot, a turn is
        refined less); docs/experiments/objects.md, "The track prior per knot"."""
        scale = self.radii.clamp_min(1e-6)[:, None, None]
        off = (self.translations - self.prior_translations) / scale
        beyond = (torch.sqrt((off**2).sum(-1) + DIST_EPS) - FREE).clamp_min(0.0)
        turn = self.rotvecs - self.prior_rotvecs
        return (beyond**2).sum(-1).mean() + (turn**2).sum(-1).mean()

    def joined(self, more: ObjectMotion) -> ObjectMotion:
        """These objects as refined so far, then ``more``'s; each keeps its own track prior."""
        extra = more.to(self.centres.device).state_dict()
        both = {k: torch.cat([v, extra[k]]) if v.dim() else v for k, v in self.state_dict().items()}
        return ObjectMotion.from_state(both)

    def state(self) -> dict[str, Tensor]:
        """Everything ``from_state`` needs, detached on the CPU."""
        return {k: v.detach().cpu().clone() for k, v in self.state_dict().items()}

    @classmethod
    def from_state(cls, state: dict[str, Tensor]) -> ObjectMotion:
        names = ("centres", "radii", "translations", "rotvecs", "spans")
        motion = cls(*(state[k] for k in names), float(state["fade"]))
        # Checkpoints written before ``behind`` was kept swept ``BEHIND`` radii behind.
        motion.load_state_dict({"behind": torch.tensor(BEHIND)} | state)
        return motion
