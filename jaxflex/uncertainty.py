"""The uncertainty box of the robot model: how far the real robot may be from the nominal one
(docs/conventions.md#uncertainty-box), and the identities of the models drawn from it (``ModelId``).

A design is judged by its absolute dwell residual over the box: at its training samples, at its
corners and on random models drawn uniformly inside it (``Box.random``, 200 by default in the
reports). The box covers, around the nominal robot of each payload case:

- Young's modulus E x (1 +- ``young``) (every link);
- the payload mass x (1 +- ``payload``);
- a structural damping ratio at the first mode in [``damping[0]``, ``damping[1]``]
  (stiffness-proportional Rayleigh damping, ``model_sets.build_model``);
- each link length (proximal l1, distal l2) +- ``length`` [m];
- the rotor inertia x (1 +- ``rotor``).

Under the paper's perfect controller the motor angles are prescribed, so the rotor inertia changes
the torques but not the vibration; the link lengths move the first mode by a fraction of a percent.
The frequencies are set mostly by E and the payload, so the training samples (``Box.grid``) span
those two axes densely, with the other factors at their nominal values (damping 0: the least
damped corner, which leaves the largest residual); the random models check every factor.
"""
from __future__ import annotations

import dataclasses
from typing import NamedTuple, Sequence

import numpy as np

from jaxflex import checks


class ModelId(NamedTuple):
    """Which model of a set: the payload case [kg] and the changes applied to the nominal robot:
    payload and Young's modulus factors, the damping ratio at the first mode (0: the robot's own),
    changes of the proximal and distal link lengths [m] and the rotor inertia factor."""

    payload: float
    payload_scale: float = 1.0
    stiffness_scale: float = 1.0
    damping_ratio: float = 0.0
    l1_delta: float = 0.0
    l2_delta: float = 0.0
    rotor_scale: float = 1.0

    @property
    def nominal(self) -> bool:
        """The nominal robot with this payload (no perturbation, no added damping)."""
        return self == ModelId(self.payload)

    @property
    def label(self) -> str:
        """Readable name, e.g. '6 kg x1.1, E x0.95' (JSON, tables, figures)."""
        zeta = f", zeta {self.damping_ratio:g}" if self.damping_ratio else ""
        lengths = (f", l1 {self.l1_delta * 1e3:+.3g} mm, l2 {self.l2_delta * 1e3:+.3g} mm"
                   if self.l1_delta or self.l2_delta else "")
        rotor = f", rotor x{self.rotor_scale:.4g}" if self.rotor_scale != 1.0 else ""
        return f"{self.payload:g} kg x{self.payload_scale:.4g}, E x{self.stiffness_scale:.4g}{zeta}{lengths}{rotor}"


@dataclasses.dataclass(frozen=True)
class Box:
    """Half-widths of the uncertainty box (module docstring): ``young``, ``payload`` and ``rotor``
    relative (0.05 = +-5 %), ``length`` [m], ``damping`` the (low, high) range of the damping ratio."""

    young: float = 0.05
    payload: float = 0.10
    damping: tuple = (0.0, 0.01)
    length: float = 0.0005
    rotor: float = 0.10

    def checked(self) -> "Box":
        """The box with float fields; ValueError naming a bad one (before anything compiles)."""
        young = checks.nonnegative("box young", self.young)
        payload = checks.nonnegative("box payload", self.payload)
        length = checks.nonnegative("box length", self.length, "m")
        rotor = checks.nonnegative("box rotor", self.rotor)
        for name, v in (("box young", young), ("box payload", payload), ("box rotor", rotor)):
            if v >= 1:
                raise ValueError(f"{name} must be a relative half-width < 1, got {v:g}")
        if length >= 0.01:
            raise ValueError(f"box length must be a half-width below 10 mm, got {length:g} m")
        lo_hi = tuple(self.damping) if np.ndim(self.damping) == 1 else ()
        if len(lo_hi) != 2:
            raise ValueError(f"box damping must be a (low, high) pair of damping ratios, got {self.damping!r}")
        lo = checks.nonnegative("box damping low", lo_hi[0])
        hi = checks.nonnegative("box damping high", lo_hi[1])
        if not lo <= hi < 1:
            raise ValueError(f"box damping must satisfy 0 <= low <= high < 1, got ({lo:g}, {hi:g})")
        return Box(young, payload, (lo, hi), length, rotor)

    def grid(self, payloads: Sequence[float], points: int = 3) -> tuple:
        """Training samples: per payload case, ``points`` x ``points`` models spanning E and the
        payload mass evenly over the box (odd ``points`` include the nominal model); damping at the
        box's low end, nominal lengths and rotor inertia. ``ModelId`` tuple."""
        b = self.checked()
        points = checks.count("points", points, 2 if b.young or b.payload else 1)
        axis = lambda w: np.linspace(1 - w, 1 + w, points) if w else np.ones(1)
        return tuple(ModelId(float(m), float(ps), float(k), b.damping[0])
                     for m in payloads for k in axis(b.young) for ps in axis(b.payload))

    def random(self, payloads: Sequence[float], n: int = 200, seed: int = 0) -> tuple:
        """``n`` models per payload case drawn uniformly in the box (every factor independent),
        reproducible from ``seed``. ``ModelId`` tuple."""
        b = self.checked()
        n = checks.count("n", n)
        rng = np.random.default_rng(seed)
        out = []
        for m in payloads:
            u = rng.uniform(-1.0, 1.0, size=(n, 6))   # E, payload, damping, l1, l2, rotor
            zeta = b.damping[0] + (b.damping[1] - b.damping[0]) * 0.5 * (u[:, 2] + 1.0)
            for k in range(n):
                out.append(ModelId(float(m), float(1 + b.payload * u[k, 1]), float(1 + b.young * u[k, 0]),
                                   float(zeta[k]), float(b.length * u[k, 3]), float(b.length * u[k, 4]),
                                   float(1 + b.rotor * u[k, 5])))
        return tuple(out)

    def corners(self, payloads: Sequence[float]) -> tuple:
        """The 2^5 corners of the box per payload case (E, payload, damping, both lengths moved
        together, rotor). ``ModelId`` tuple."""
        b = self.checked()
        out = []
        for m in payloads:
            for k in (1 - b.young, 1 + b.young):
                for ps in (1 - b.payload, 1 + b.payload):
                    for zeta in b.damping:
                        for dl in (-b.length, b.length):
                            for rs in (1 - b.rotor, 1 + b.rotor):
                                out.append(ModelId(float(m), float(ps), float(k), float(zeta), float(dl), float(dl),
                                                   float(rs)))
        return tuple(dict.fromkeys(out))
