"""Range-sensor noise: what a real depth camera or lidar does to the ideal ray-cast ranges.

Every effect is a number in :data:`PRESETS` (the one place the ``sensor.noise`` presets are defined) and
every random draw comes from the generator handed to :meth:`NoiseModel.reset` (the env's ``np_random``),
so a seed reproduces a run. Effects, in the order they are applied:

1. a per-episode range scale error (calibration), drawn at ``reset``;
2. Gaussian range noise whose standard deviation grows with range: ``range_std + range_std_per_m * r``
   (stereo and time-of-flight sensors get worse with distance);
3. quantisation of the range to ``quantization`` metres;
4. random drop-outs (single rays return nothing);
5. drop-out patches (sun glare, dust clouds, specular rock): elliptic blobs in the range image, their
   number per frame Poisson-distributed;
6. spurious near returns (dust in front of the sensor): a ray returns a random range short of its true one.

``noise_level`` multiplies the amplitudes and probabilities (the fields in :data:`SCALED`); sizes and
ranges of effects stay as they are.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from diana_lab.core.validation import ConfigError

__all__ = ["PRESETS", "SCALED", "NoiseModel", "NoiseParams"]


@dataclass(frozen=True)
class NoiseParams:
    range_std: float = 0.0  # m, standard deviation of the range error at zero range
    range_std_per_m: float = 0.0  # m of standard deviation added per metre of range
    range_scale_std: float = 0.0  # per-episode relative range scale error (std of the factor - 1)
    quantization: float = 0.0  # m, range resolution (0: none)
    dropout: float = 0.0  # probability that a return is lost
    patch_rate: float = 0.0  # expected number of drop-out patches per frame
    patch_radius: float = 0.08  # patch radius as a fraction of the image's larger side (0.5x .. 1.5x)
    spurious: float = 0.0  # probability per ray of a spurious near return
    spurious_max_range: float = 1.5  # m, spurious returns lie between the sensor's min_range and this

    def scaled(self, level: float) -> NoiseParams:
        """These parameters with every amplitude/probability multiplied by ``level`` (probabilities <= 1)."""
        values = {k: getattr(self, k) * level for k in SCALED}
        values["dropout"] = min(values["dropout"], 1.0)
        values["spurious"] = min(values["spurious"], 1.0)
        return dataclasses.replace(self, **values)

    @cached_property
    def active(self) -> bool:
        """Whether any effect is on (cached: the parameters are frozen, and every frame asks)."""
        return any(getattr(self, k) > 0 for k in SCALED)


SCALED = (
    "range_std",
    "range_std_per_m",
    "range_scale_std",
    "quantization",
    "dropout",
    "patch_rate",
    "spurious",
)

PRESETS: dict[str, NoiseParams] = {
    "none": NoiseParams(),
    # an outdoor RGB-D camera / lidar on a good day: ~2 cm at 2 m, ~6 cm at 10 m, 1 % drop-outs
    "realistic": NoiseParams(
        range_std=0.01,
        range_std_per_m=0.005,
        range_scale_std=0.005,
        quantization=0.005,
        dropout=0.01,
        patch_rate=0.2,
        patch_radius=0.08,
        spurious=0.001,
        spurious_max_range=1.0,
    ),
    # dusty, low sun: large errors, frequent glare patches and dust returns
    "harsh": NoiseParams(
        range_std=0.02,
        range_std_per_m=0.015,
        range_scale_std=0.02,
        quantization=0.02,
        dropout=0.05,
        patch_rate=1.0,
        patch_radius=0.12,
        spurious=0.01,
        spurious_max_range=2.0,
    ),
}


class NoiseModel:
    """Applies one preset (scaled by ``level``) to the raw hit distances of an ``(H, W)`` ray image."""

    def __init__(self, preset: str, level: float, image_shape: tuple[int, int], min_range: float) -> None:
        if preset not in PRESETS:
            names = ", ".join(map(repr, PRESETS))
            raise ConfigError(f"sensor.noise: expected one of {names}, got {preset!r}")
        self.params = PRESETS[preset].scaled(level)
        self.image_shape = image_shape
        self.min_range = float(min_range)
        self.rng = np.random.default_rng(0)
        self.scale = 1.0
        rows, cols = np.indices(image_shape, dtype=np.float32)
        self._rows, self._cols = rows.reshape(-1), cols.reshape(-1)

    @property
    def active(self) -> bool:
        return self.params.active

    def reset(self, rng: np.random.Generator) -> None:
        """Start an episode: take the generator and draw the per-episode calibration error."""
        self.rng = rng
        std = self.params.range_scale_std
        self.scale = 1.0 + float(rng.normal(0.0, std)) if std > 0 else 1.0

    def apply(self, t: np.ndarray) -> np.ndarray:
        """Noisy copy of the hit distances ``t`` (``(H*W,)``; ``inf`` = no hit, and marks lost returns)."""
        p, rng = self.params, self.rng
        r = np.array(t, dtype=np.float32, copy=True)
        n = r.size
        hit = np.flatnonzero(np.isfinite(r))
        rh = r[hit]
        if self.scale != 1.0:
            rh *= self.scale
        if p.range_std or p.range_std_per_m:
            rh += rng.standard_normal(rh.size, dtype=np.float32) * (p.range_std + p.range_std_per_m * rh)
        if p.quantization:
            rh = np.round(rh / p.quantization) * p.quantization
        r[hit] = rh
        if p.dropout:
            r[rng.random(n, dtype=np.float32) < p.dropout] = np.inf
        if p.patch_rate:
            self._patches(r)
        if p.spurious:
            dust = np.flatnonzero(rng.random(n, dtype=np.float32) < p.spurious)
            if dust.size:
                lo = self.min_range
                hi = max(p.spurious_max_range, lo + 1e-3)
                r[dust] = np.minimum(r[dust], rng.uniform(lo, hi, dust.size).astype(np.float32))
        return r

    def _patches(self, r: np.ndarray) -> None:
        rng, p = self.rng, self.params
        h, w = self.image_shape
        size = max(h, w)
        for _ in range(rng.poisson(p.patch_rate)):
            cy, cx = rng.uniform(0, h), rng.uniform(0, w)
            ry, rx = p.patch_radius * size * rng.uniform(0.5, 1.5, 2)
            inside = ((self._rows - cy) / max(ry, 0.5)) ** 2 + ((self._cols - cx) / max(rx, 0.5)) ** 2 <= 1.0
            r[inside] = math.inf
