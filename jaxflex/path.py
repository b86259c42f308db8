"""The blended Adept pick-and-place path (paper Fig. 1, Section 3; docs/conventions.md#adept-cycle-and-blends),
parametrized by arc length.

The cycle goes from the pick point up by ``h`` (along ``lift``), across by ``l`` to above the place
point, and down by ``h``. Each of the two corners is replaced by a blend (``jaxflex.blends``) that
starts ``d`` before the corner on the vertical leg and ends ``e`` after it on the horizontal leg; the
second corner is the mirror image of the first (with its own d, e, n). With d = e = h the path is
blend, straight traverse of l - 2e, mirrored blend.

Coordinates: world frame of the robot (m). The cycle frame has its origin at the pick point, x along
the traverse (pick -> place) and y along the lift direction.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxflex.blends import Blend, Frame, blend_frame, check_blend_args, make_blend


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Cycle:
    """Placement of the Adept cycle.

    Attributes:
        pick: (2,) pick point [m].
        place: (2,) place point [m]; the traverse length is l = |place - pick|.
        h: lift height [m].
        lift: (2,) unit lift direction, perpendicular to place - pick.
    """

    pick: jax.Array
    place: jax.Array
    h: jax.Array
    lift: jax.Array

    @property
    def l(self):
        """Traverse length [m]."""
        return jnp.linalg.norm(self.place - self.pick)

    @property
    def basis(self):
        """(2, 2) matrix whose columns are the cycle frame axes (traverse, lift) in the world frame."""
        t = (self.place - self.pick) / self.l
        return jnp.stack([t, self.lift], axis=1)


def make_cycle(pick, place, h=0.025, lift=(0.0, 1.0)) -> Cycle:
    """Adept cycle from pick to place with lift height h [m] along the unit vector ``lift``."""
    pick = np.asarray(pick, dtype=float)
    place = np.asarray(place, dtype=float)
    lift = np.asarray(lift, dtype=float)
    if pick.shape != (2,) or place.shape != (2,) or lift.shape != (2,):
        raise ValueError("pick, place and lift must be 2-vectors")
    if np.ndim(h) != 0:
        raise ValueError(f"lift height h must be a scalar, got shape {np.shape(h)}")
    for name, v in (("pick", pick), ("place", place), ("lift", lift), ("h", h)):
        if not np.all(np.isfinite(v)):
            raise ValueError(f"cycle parameter {name} must be finite, got {v}")
    if not h > 0:
        raise ValueError(f"lift height h must be > 0 m, got {h}")
    l = np.linalg.norm(place - pick)
    if l <= 0:
        raise ValueError("pick and place points coincide")
    if abs(np.linalg.norm(lift) - 1.0) > 1e-9:
        raise ValueError(f"lift must be a unit vector, got {lift.tolist()}")
    if abs(np.dot(lift, place - pick)) > 1e-9 * l:
        raise ValueError("lift direction must be perpendicular to the traverse (place - pick)")
    put = lambda v: jax.device_put(np.asarray(v, dtype=np.float64))       # no device computation
    return Cycle(pick=put(pick), place=put(place), h=put(float(h)), lift=put(lift))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Path:
    """Blended Adept path: the cycle and its two corner blends (corner 1 at the pick side)."""

    cycle: Cycle
    blend1: Blend
    blend2: Blend

    @property
    def kind(self) -> str:
        return self.blend1.kind

    @property
    def breaks(self):
        """(6,) arc length at the segment boundaries: 0, blend 1 start, blend 1 end, blend 2 start,
        blend 2 end, total length L [m]."""
        c, b1, b2 = self.cycle, self.blend1, self.blend2
        s1 = c.h - b1.d
        s2 = s1 + b1.length
        s3 = s2 + c.l - b1.e - b2.e
        s4 = s3 + b2.length
        return jnp.stack([jnp.zeros_like(s1), s1, s2, s3, s4, s4 + c.h - b2.d])

    @property
    def length(self):
        """Total arc length L [m]."""
        return self.breaks[-1]


def _is_concrete(*xs):
    return not any(isinstance(x, jax.core.Tracer) for x in xs)


def check_path_args(cycle: Cycle, blend: str, d, e, n, d2, e2, n2) -> None:
    """Eager validation of the blend parameters against the cycle (values that are traced are skipped)."""
    check_blend_args(blend, d, e, n)
    check_blend_args(blend, d2, e2, n2, names=("d2", "e2", "n2"))
    if _is_concrete(d, d2, cycle.h):
        h = float(cycle.h)
        for name, v in (("d", d), ("d2", d2)):
            if float(v) > h * (1 + 1e-12):
                raise ValueError(f"blend parameter {name} = {float(v):g} m exceeds the lift height "
                                 f"h = {h:g} m: the blend would start below the pick/place point")
    if _is_concrete(e, e2, cycle.pick, cycle.place):
        l = float(cycle.l)
        if float(e) + float(e2) > l * (1 + 1e-12):
            raise ValueError(f"blend parameters e = {float(e):g} m and e2 = {float(e2):g} m exceed the "
                             f"traverse l = {l:g} m together (each must be <= l/2 for a symmetric "
                             "path): the two blends would overlap")


def make_path(cycle: Cycle, blend: str = "lame", d=0.025, e=None, n=3.0,
              d2=None, e2=None, n2=None) -> Path:
    """Blended Adept path.

    Args:
        cycle: placement (``make_cycle`` or a preset).
        blend: blend family, one of ``jaxflex.blends.BLENDS``.
        d, e, n: corner-1 blend parameters [m, m, -]; e defaults to d.
        d2, e2, n2: corner-2 parameters (default: same as corner 1, a symmetric path).
    Raises:
        ValueError: unknown family, d > h, e1 + e2 > l (e > l/2 for a symmetric path), n < 2, ...
    """
    e = d if e is None else e
    d2 = d if d2 is None else d2
    e2 = e if e2 is None else e2
    n2 = n if n2 is None else n2
    check_path_args(cycle, blend, d, e, n, d2, e2, n2)
    return Path(cycle=cycle, blend1=make_blend(blend, d, e, n), blend2=make_blend(blend, d2, e2, n2))


def path_frame(path: Path, s) -> Frame:
    """Position and arc-length derivatives (world frame) at arc length s in [0, L] (scalar)."""
    c, b1, b2 = path.cycle, path.blend1, path.blend2
    br = path.breaks
    s = jnp.clip(s, 0.0, br[-1])
    seg = jnp.sum(s >= br[1:5])               # 0 line up, 1 blend 1, 2 traverse, 3 blend 2, 4 line down
    in2 = seg >= 3
    blend = jax.tree_util.tree_map(lambda a, b: jnp.where(in2, b, a), b1, b2)
    sigma = jnp.where(in2, b2.length - (s - br[3]), s - br[1])
    f = blend_frame(blend, sigma)
    flip = jnp.array([1.0, -1.0])
    # blend 1: shift to the corner; blend 2: mirror x and traverse backwards
    b1_pos = jnp.stack([f.pos[0], c.h - b1.d + f.pos[1]])
    b2_pos = jnp.stack([c.l - f.pos[0], c.h - b2.d + f.pos[1]])
    zero = jnp.zeros(2)
    up, across, down = jnp.array([0.0, 1.0]), jnp.array([1.0, 0.0]), jnp.array([0.0, -1.0])
    cases = [
        Frame(jnp.stack([0.0, s]), up, zero, zero),
        Frame(b1_pos, f.tangent, f.curv, f.dcurv),
        Frame(jnp.stack([b1.e + s - br[2], c.h]), across, zero, zero),
        Frame(b2_pos, f.tangent * flip, -f.curv * flip, f.dcurv * flip),
        Frame(jnp.stack([c.l, c.h - b2.d - (s - br[4])]), down, zero, zero),
    ]
    local = jax.tree_util.tree_map(lambda *xs: jnp.select([seg == i for i in range(5)], xs), *cases)
    basis = c.basis
    return Frame(c.pick + basis @ local.pos, basis @ local.tangent, basis @ local.curv,
                 basis @ local.dcurv)
