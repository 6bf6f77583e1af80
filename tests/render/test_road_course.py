"""Road sensors against the analytic point source: E = I·cosθ/r² at every sensor, the
5 lx distance to 1 % on straight and curved roads."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from lightsim.errors import InputError
from lightsim.render.road_course import (
    Approach,
    LampPair,
    approach_by_name,
    crossing_distance,
    distance_grid,
    exceedance,
    sensor_curves,
)

I0 = 20_000.0  # cd, every direction
LANE = 3.6


def _const(h, v):
    return np.full(np.broadcast(np.asarray(h), np.asarray(v)).shape, I0)


def _analytic(kind: str, radius: float | None, offset: float, height: float,
              lamps: LampPair, s: np.ndarray) -> np.ndarray:
    """Both lamps' E at sensors ``offset`` m right of the lane centre (written from the
    circle's centre, independently of the module)."""
    s = np.asarray(s, dtype=float)
    if kind == "straight":
        px, pz, tx, tz = np.full_like(s, offset), s, np.zeros_like(s), np.ones_like(s)
    else:
        phi = s / radius
        sign = 1.0 if kind == "right" else -1.0
        # circle centre (sign·R, 0); a point at radius R − sign·offset from it
        rr = radius - sign * offset
        px = sign * radius - sign * rr * np.cos(phi)
        pz = rr * np.sin(phi)
        tx, tz = sign * np.sin(phi), np.cos(phi)
    total = np.zeros_like(s)
    for lx in lamps.lamp_x().values():
        dx, dy, dz = px - lx, height - lamps.mount_height_m, pz
        r = np.sqrt(dx * dx + dy * dy + dz * dz)
        cos = (dx * tx + dz * tz) / r
        total += I0 * cos / r**2
    return total


@pytest.mark.parametrize("name", ["straight", "left-150", "right-150", "left-250",
                                  "right-250"])
def test_point_source_every_sensor(name: str) -> None:
    ap = approach_by_name(name, LANE)
    lamps = LampPair(0.65, 1.2)
    s = distance_grid((2.0, 150.0), 0.5)
    curves = {c.sensor: c for c in sensor_curves(_const, ap, lamps, s)}
    for sensor, off, y in (("right_edge", 0.5 * LANE, 0.25), ("left_edge", -1.5 * LANE, 0.25),
                           ("glare", -LANE, 1.1)):
        want = _analytic(ap.kind, ap.radius_m, off, y, lamps, s)
        np.testing.assert_allclose(curves[sensor].lux, want, rtol=1e-12)


@pytest.mark.parametrize("name", ["straight", "left-150", "right-150", "right-250"])
def test_five_lux_distance_to_one_percent(name: str) -> None:
    ap = approach_by_name(name, LANE)
    lamps = LampPair(0.65, 1.2)
    s = distance_grid((0.25, 200.0), 0.25)
    curve = sensor_curves(_const, ap, lamps, s)[0]  # right edge
    f = lambda x: _analytic(ap.kind, ap.radius_m, 0.5 * LANE, 0.25, lamps,  # noqa: E731
                            np.array([x]))[0] - 5.0
    exact = brentq(f, 20.0, 199.0)
    got = crossing_distance(curve.s_m, curve.lux, 5.0)["distance_m"]
    assert got == pytest.approx(exact, rel=0.01)


def test_left_traffic_mirrors_the_straight_road() -> None:
    s = distance_grid((1.0, 80.0), 1.0)
    # a far field with more light to the right (h > 0)
    def skew(h, v):
        return 1000.0 * (1.0 + 0.5 * np.tanh(np.asarray(h)))

    def mirrored(h, v):
        return skew(-np.asarray(h), v)

    ap = Approach("straight")
    right = {c.sensor: c for c in sensor_curves(skew, ap, LampPair(traffic="right"), s)}
    left = {c.sensor: c for c in sensor_curves(mirrored, ap, LampPair(traffic="left"), s)}
    np.testing.assert_allclose(left["right_edge"].lux, right["left_edge"].lux, rtol=1e-12)
    np.testing.assert_allclose(left["glare"].lux, right["glare"].lux, rtol=1e-12)


def test_pitch_reprojection_moves_the_beam() -> None:
    """A beam with a horizontal cut-off: pitching up by p moves where a road point falls
    below it exactly as the analytic geometry says."""
    def cutoff(h, v):
        return np.where(np.asarray(v) < -1.0, 30_000.0, 0.0) + 0 * np.asarray(h)

    ap = Approach("straight")
    s = distance_grid((1.0, 100.0), 0.01)
    for pitch in (-0.5, 0.0, 0.5):
        lamps = LampPair(0.65, 0.0, pitch)
        c = sensor_curves(cutoff, ap, lamps, s)[0]
        lit = s[np.nan_to_num(c.lux) > 0]
        # the edge sensor (0.4 m below the lamp) is lit while the elevation the lamp,
        # pitched up by p, sees it at (its world elevation − p) lies below −1°
        want_far = 0.4 / np.tan(np.radians(1.0 - pitch))
        assert lit.max() == pytest.approx(want_far, abs=0.02)


def test_interval_from_sets_contains_truth() -> None:
    rng = np.random.default_rng(3)
    factors = 1.0 + 0.05 * rng.standard_normal(8)
    factors *= 1.0 / factors.mean()

    def sets(h, v):
        return np.stack([_const(h, v) * f for f in factors])

    s = distance_grid((1.0, 150.0), 0.25)
    curve = sensor_curves(_const, Approach("straight"), LampPair(), s, sets)[0]
    assert curve.lux_lo is not None
    assert np.all(curve.lux_lo <= curve.lux + 1e-9) and np.all(curve.lux <= curve.lux_hi + 1e-9)
    lo = crossing_distance(s, curve.lux_lo, 5.0)["distance_m"]
    hi = crossing_distance(s, curve.lux_hi, 5.0)["distance_m"]
    mid = crossing_distance(s, curve.lux, 5.0)["distance_m"]
    assert lo < mid < hi


def test_crossing_edge_cases() -> None:
    s = np.array([1.0, 2.0, 3.0])
    assert crossing_distance(s, np.array([0.1, 0.2, 0.1]), 5.0)["distance_m"] is None
    assert crossing_distance(s, np.array([9.0, 8.0, 7.0]), 5.0) == {"distance_m": 3.0,
                                                                      "beyond": True}
    assert crossing_distance(s, np.array([np.nan, 6.0, 4.0]), 5.0)["distance_m"] == 2.5
    assert crossing_distance(np.array([]), np.array([]), 5.0)["distance_m"] is None
    assert exceedance(s, np.array([2.0, 0.5, 3.0]), 1.0) == [[1.0, 1.0], [3.0, 3.0]]


@pytest.mark.parametrize("bad", [0.0, -150.0, float("nan"), float("inf")])
def test_bad_radius(bad: float) -> None:
    with pytest.raises(InputError, match="radius"):
        Approach("left", bad)


def test_bad_names_and_lamps() -> None:
    with pytest.raises(InputError):
        approach_by_name("left-abc")
    with pytest.raises(InputError):
        approach_by_name("uphill-100")
    with pytest.raises(InputError):
        LampPair(mount_height_m=0.0)
    with pytest.raises(InputError):
        distance_grid((10.0, 5.0), 1.0)
