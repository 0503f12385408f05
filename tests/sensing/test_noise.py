"""Noise models: statistics as configured, scaled by noise_level, reproducible from the generator."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from diana_lab.config.sensing import NOISE_PRESETS
from diana_lab.sensing.noise import PRESETS, NoiseModel, NoiseParams
from tests.sensing.conftest import make_sensor, plane_world

N = 40_000


def model(level: float = 1.0, shape: tuple[int, int] = (200, 200), **params) -> NoiseModel:
    m = NoiseModel("none", level, shape, min_range=0.2)
    m.params = NoiseParams(**params).scaled(level)
    m.reset(np.random.default_rng(0))
    return m


def test_presets_are_the_names_the_config_accepts():
    assert set(PRESETS) == set(NOISE_PRESETS)
    assert not PRESETS["none"].active and PRESETS["realistic"].active
    # harsh is worse than realistic in every scaled quantity
    for key in ("range_std", "range_std_per_m", "dropout", "patch_rate", "spurious"):
        assert getattr(PRESETS["harsh"], key) > getattr(PRESETS["realistic"], key)


def test_range_noise_std_grows_with_range():
    m = model(range_std=0.01, range_std_per_m=0.01)
    near = m.apply(np.full(N, 1.0, np.float32)) - 1.0
    far = m.apply(np.full(N, 8.0, np.float32)) - 8.0
    assert near.std() == pytest.approx(0.02, rel=0.05)
    assert far.std() == pytest.approx(0.09, rel=0.05)
    assert abs(far.mean()) < 0.005
    # noise_level scales the amplitude
    doubled = model(2.0, range_std=0.01, range_std_per_m=0.01).apply(np.full(N, 8.0, np.float32)) - 8.0
    assert doubled.std() == pytest.approx(0.18, rel=0.05)


def test_dropout_fraction_and_misses_stay_misses():
    t = np.full(N, 5.0, np.float32)
    t[:1000] = np.inf
    r = model(dropout=0.1).apply(t)
    assert np.isinf(r[:1000]).all()
    assert np.isinf(r[1000:]).mean() == pytest.approx(0.1, abs=0.01)
    assert np.isinf(model(0.5, dropout=0.1).apply(t)[1000:]).mean() == pytest.approx(0.05, abs=0.01)


def test_patches_drop_contiguous_blobs():
    m = model(shape=(100, 100), patch_rate=2.0, patch_radius=0.1)
    dropped = [np.isinf(m.apply(np.full(10_000, 3.0, np.float32))).reshape(100, 100) for _ in range(20)]
    frac = np.mean([d.mean() for d in dropped])
    assert 0.02 < frac < 0.5
    # a dropped pixel's right neighbour is almost always dropped too (blobs, not salt-and-pepper)
    pairs = np.concatenate([(d[:, :-1] & d[:, 1:]).ravel()[d[:, :-1].ravel()] for d in dropped])
    assert pairs.mean() > 0.8


def test_spurious_near_returns_and_quantisation():
    r = model(spurious=0.05, spurious_max_range=1.0).apply(np.full(N, 8.0, np.float32))
    near = r < 8.0
    assert near.mean() == pytest.approx(0.05, abs=0.005)
    assert r[near].min() >= 0.2 and r[near].max() <= 1.0
    q = model(quantization=0.05).apply(np.random.default_rng(1).uniform(1, 9, N).astype(np.float32))
    np.testing.assert_allclose(q / 0.05, np.round(q / 0.05), atol=1e-3)


def test_sensor_noise_is_reproducible_from_the_seed():
    world = plane_world(0.0)
    sensor = make_sensor("depth_camera", world, noise="harsh")
    pose = (np.array([0.0, 0.0, 0.1]), np.zeros(3))

    def frames(seed):
        sensor.reset(np.random.default_rng(seed))
        return [sensor.capture(*pose).ranges for _ in range(3)]

    a, b, c = frames(7), frames(7), frames(8)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[0], c[0], equal_nan=True)
    assert not np.array_equal(a[0], a[1], equal_nan=True)  # a new draw every frame
    clean = make_sensor("depth_camera", world).capture(*pose)
    for f in a:  # noise never returns values outside the sensor's limits
        assert np.nanmin(f) >= sensor.cfg.min_range and np.nanmax(f) <= sensor.cfg.max_range
    assert np.isnan(a[0]).sum() > np.isnan(clean.ranges).sum()


def test_noise_level_zero_is_the_clean_sensor():
    world = plane_world(0.0)
    pose = (np.array([0.0, 0.0, 0.1]), np.array([0.0, 0.0, 0.3]))
    noisy = make_sensor("depth_camera", world, noise="harsh", noise_level=0.0)
    clean = make_sensor("depth_camera", world)
    np.testing.assert_array_equal(noisy.capture(*pose).ranges, clean.capture(*pose).ranges)
    assert dataclasses.asdict(noisy.noise.params)["dropout"] == 0.0
