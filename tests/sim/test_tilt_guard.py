"""The rover's tilt fault protection (``robot.tilt_guard_deg``): a drive halts where the tilt passes the guard,
backs ``robot.guard_retreat`` metres along its own track (tripped while turning in place, straight back; after
``robot.guard_pause_s`` standing still, at ``robot.guard_retreat_speed``), and reports where the guard tripped
(``hazard_xy``).
Both dynamics models, on a terrain whose cross slope grows along the drive until the rover would tip."""

import math

import numpy as np
import pytest

from diana_lab.config import ConfigError, build, to_object
from diana_lab.sim.controller import TurnThenDrive
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import World

CROSS_DEG = 45.0  # the cross slope the ramp reaches (the Jackal tips at 35)


def twisting_ramp(size: float = 20.0, length: float = 4.0) -> World:
    """Flat for x <= 0; from there the cross slope (up towards +y) grows linearly to CROSS_DEG at x = length."""
    x = np.linspace(-size / 2, size / 2, 161)
    gx, gy = np.meshgrid(x, x)
    grid = gy * math.tan(math.radians(CROSS_DEG)) * np.clip(gx / length, 0.0, 1.0)
    return World("twist", Terrain(grid, size, size))


def robot(**overrides):
    return to_object("robot", {**to_object("robot", "jackal").__dict__, **overrides})


def make(name: str, world: World, rover):
    cfg = to_object("dynamics", {"name": name})
    return build(cfg, world, rover), TurnThenDrive(cfg.controller, rover)


@pytest.fixture(scope="module")
def ramp():
    return twisting_ramp()


def test_without_the_guard_the_drive_tips_over(ramp):
    dyn, ctl = make("kinematic", ramp, robot())
    dyn.reset(np.array([-2.0, 0.0]), 0.0)
    result = dyn.execute(np.array([6.0, 0.0]), ctl)
    assert result.outcome == "tipover"
    assert result.hazard_xy is None


@pytest.mark.parametrize(
    "retreat, pause, speed", [(0.0, 0.0, None), (1.2, 0.0, None), (50.0, 0.0, None), (1.2, 0.5, 0.15)]
)
def test_kinematic_guard_halts_backs_off_and_reports_where(ramp, retreat, pause, speed):
    guard = 20.0
    rover = robot(tilt_guard_deg=guard, guard_retreat=retreat, guard_pause_s=pause, guard_retreat_speed=speed)
    dyn, ctl = make("kinematic", ramp, rover)
    dyn.reset(np.array([-2.0, 0.0]), 0.0)
    result = dyn.execute(np.array([6.0, 0.0]), ctl)
    assert result.outcome == "halted" and not result.failed
    # the guard tripped at the first path sample over it: there the tilt is above the guard, before it below
    hx, hy = result.hazard_xy
    assert hy == pytest.approx(0.0, abs=1e-9)
    spacing = dyn.cfg.sample_spacing
    z, rp = dyn._poses(np.array([[hx, hy], [hx - spacing, hy]]), np.zeros(2))
    tilt = np.degrees(np.arccos(np.cos(rp[:, 0]) * np.cos(rp[:, 1])))
    assert tilt[0] > guard >= tilt[1] - 1e-6
    # the rover stopped one sample short of it and backed off along its track (never past where it started)
    stop = hx - spacing
    end = max(stop - retreat, -2.0)
    assert dyn.state.xy[0] == pytest.approx(end, abs=spacing + 1e-6)
    assert dyn.state.xy[1] == pytest.approx(0.0, abs=1e-9) and dyn.state.yaw == pytest.approx(0.0)
    assert dyn.state.tilt_deg < guard
    # the trace goes out and back; length and time count both ways
    trace_x = result.trace_xy[:, 0]
    assert trace_x.max() == pytest.approx(stop, abs=1e-6)
    assert trace_x[-1] == pytest.approx(dyn.state.xy[0])
    assert result.path_length == pytest.approx((stop + 2.0) + (stop - dyn.state.xy[0]), abs=1e-6)
    assert np.all(np.diff(result.trace_t) >= 0)
    out, back = stop + 2.0, stop - dyn.state.xy[0]
    backing = pause + back / rover.retreat_speed if retreat > 0 else 0.0  # a rover that backs off no metres
    assert result.duration == pytest.approx(out / rover.cruise_speed + backing, rel=1e-6)
    assert result.max_tilt_deg <= guard


def test_the_guard_trips_before_a_tip_between_two_samples(ramp):
    """A tilt that jumps from under the guard to over the tip-over limit between two samples crossed the guard
    first (it is continuous along the path): halted, not tipped."""
    rover = robot(tilt_guard_deg=34.9)
    dyn, ctl = make("kinematic", ramp, rover)
    dyn.reset(np.array([-2.0, 0.0]), 0.0)
    result = dyn.execute(np.array([6.0, 0.0]), ctl)
    assert result.outcome == "halted"


@pytest.mark.parametrize("retreat", [0.0, 1.2])
def test_a_halt_while_turning_in_place_bars_that_way_and_backs_straight_off(retreat):
    """On a uniform 10 deg slope a 5 deg guard trips at the turn's first sample: the rover backs
    ``guard_retreat`` straight behind its heading (there is no track to back along; standing still, the next
    turn would trip again), unguarded, and reports half a rover length towards the heading it was turning to."""
    from tests.sim.test_kinematic import slope_world

    rover = robot(tilt_guard_deg=5.0, guard_retreat=retreat)
    dyn, ctl = make("kinematic", slope_world(10.0), rover)
    dyn.reset(np.array([3.0, 0.0]), 0.0)
    result = dyn.execute(np.array([3.0, 3.0]), ctl)  # a quarter turn to the left first
    assert result.outcome == "halted" and result.path_length == pytest.approx(retreat)
    np.testing.assert_allclose(dyn.state.xy, [3.0 - retreat, 0.0], atol=1e-9)
    assert dyn.state.yaw == pytest.approx(0.0)  # facing as it was: it backed, it did not turn
    np.testing.assert_allclose(result.hazard_xy, [3.0, 0.5 * rover.length], atol=1e-9)
    np.testing.assert_allclose(result.trace_xy[-1], dyn.state.xy)
    assert len(result.trace_t) == len(result.trace_xy) and np.all(np.diff(result.trace_t) >= 0)
    assert result.duration == pytest.approx(result.trace_t[-1])


def test_the_guard_re_arms_while_backing_off():
    """Backing straight off from flat ground towards a 20 deg cross slope that starts 0.6 m behind: under a 15
    deg guard the back-off stops at the last sample under it, short of its 1.2 m (the guard re-armed at the
    start, where the tilt was under it), and the waypoint keeps the halt's own hazard."""
    from diana_lab.sim.state import WaypointResult

    x = np.linspace(-10.0, 10.0, 401)
    gx, gy = np.meshgrid(x, x)
    world = World("cross", Terrain(np.where(gx < -0.6, math.tan(math.radians(20.0)) * gy, 0.0), 20.0, 20.0))
    dyn, _ = make("kinematic", world, robot(tilt_guard_deg=15.0, guard_pause_s=0.3, guard_retreat_speed=0.5))
    dyn.reset(np.array([0.0, 0.0]), 0.0)
    hazard = np.array([0.5, 0.0])
    halted = WaypointResult(
        "halted", 1.0, 0.0, np.zeros((1, 2)), np.zeros(1), np.zeros((1, 2)), "trip", np.zeros(1), hazard_xy=hazard
    )
    result = dyn._back_off(halted)
    assert result.outcome == "halted" and result.detail == "trip"
    assert result.path_length < 1.0 and dyn.state.tilt_deg < 15.0  # short of the 1.2 m, still under the guard
    assert result.trace_tilt_deg.max() < 15.0
    np.testing.assert_allclose(result.hazard_xy, hazard)
    assert result.duration == pytest.approx(1.0 + 0.3 + result.path_length / 0.5)  # the halt, the pause, 0.5 m/s


def test_backing_off_a_turn_halt_stops_at_a_slope_too_steep_to_climb_backwards():
    """Facing down a 10 deg slope that steepens to 40 deg 0.5 m behind the rover (uphill): backing off would
    climb it backwards, nose down past the 25 deg the Jackal can climb: the back-off stops at its foot."""
    x = np.linspace(-10.0, 10.0, 401)
    gx, gy = np.meshgrid(x, x)
    slope = np.where(gx < -0.5, math.tan(math.radians(10.0)), math.tan(math.radians(40.0)))
    heights = np.cumsum(slope, axis=1) * (x[1] - x[0])  # rising towards +x
    world = World("steepening", Terrain(heights - heights[200, 200], 20.0, 20.0))
    dyn, ctl = make("kinematic", world, robot(tilt_guard_deg=5.0))
    dyn.reset(np.array([-1.5, 0.0]), math.pi)  # facing -x, down the slope; +x (behind) gets steep
    result = dyn.execute(np.array([-1.5, 3.0]), ctl)
    assert result.outcome == "halted"
    assert 0.0 < result.path_length < 1.2 and dyn.state.xy[0] < -0.3


def test_a_slope_that_stops_a_turn_in_place_reports_the_way_it_was_turning_to():
    """Across a 30 deg slope (tilt under the Jackal's 35), turning to face uphill raises the nose past the 25 deg
    it can climb before the turn ends: stuck while turning, reported half a rover length uphill."""
    from tests.sim.test_kinematic import slope_world

    rover = robot()
    dyn, ctl = make("kinematic", slope_world(30.0), rover)
    dyn.reset(np.array([3.0, 0.0]), math.pi / 2)
    result = dyn.execute(np.array([6.0, 0.0]), ctl)
    assert result.outcome == "stuck" and result.path_length == 0.0
    np.testing.assert_allclose(result.hazard_xy, [3.0 + 0.5 * rover.length, 0.0], atol=1e-9)


def test_a_slope_too_steep_to_climb_reports_its_foot(ramp):
    from tests.sim.test_kinematic import slope_world

    world = slope_world(30.0)
    dyn, ctl = make("kinematic", world, robot())
    dyn.reset(np.array([-3.0, 0.0]), 0.0)
    result = dyn.execute(np.array([3.0, 0.0]), ctl)
    assert result.outcome == "stuck"
    assert -0.5 < result.hazard_xy[0] < 0.5 and dyn.state.xy[0] < result.hazard_xy[0]


def test_physics_guard_halts_and_backs_off(ramp):
    guard, retreat = 15.0, 1.0
    dyn, ctl = make("physics", ramp, robot(tilt_guard_deg=guard, guard_retreat=retreat))
    try:
        dyn.reset(np.array([-2.0, 0.0]), 0.0)
        result = dyn.execute(np.array([6.0, 0.0]), ctl)
        assert result.outcome == "halted", result.detail
        assert "tilt guard" in result.detail
        hx, hy = result.hazard_xy
        assert 0.5 < hx < 3.0  # on the ramp, before it gets steep enough to tip
        assert hx - dyn.state.xy[0] >= retreat - 0.05  # backed off along its track
        assert dyn.state.tilt_deg < guard
        assert result.path_length >= 2.0 + hx + retreat - 0.3  # out and back
    finally:
        dyn.close()


def test_physics_guard_pauses_then_backs_off_slowly(ramp):
    """With ``guard_pause_s`` the wheels hold after the trip (the rover stays where it stopped), then it backs
    off at ``guard_retreat_speed``: the same halt as without, taking the pause and the slower reverse longer."""
    guard, retreat, pause, speed = 15.0, 1.0, 1.0, 0.15
    durations = {}
    for key, extra in {"at once": {}, "paused": {"guard_pause_s": pause, "guard_retreat_speed": speed}}.items():
        dyn, ctl = make("physics", ramp, robot(tilt_guard_deg=guard, guard_retreat=retreat, **extra))
        try:
            dyn.reset(np.array([-2.0, 0.0]), 0.0)
            result = dyn.execute(np.array([6.0, 0.0]), ctl)
            assert result.outcome == "halted" and "tilt guard" in result.detail, result.detail
            assert result.hazard_xy[0] - dyn.state.xy[0] >= retreat - 0.05  # the whole back-off, in time
            durations[key] = result.duration
            if extra:
                trip = int(np.argmax(result.trace_tilt_deg > guard))
                held = result.trace_xy[trip : trip + round(pause / dyn._tick)]
                assert np.hypot(*(held - held[0]).T).max() < 0.05  # standing still through the pause
        finally:
            dyn.close()
    slower = pause + retreat * (1.0 / speed - 1.0 / robot().cruise_speed)  # ~4.6 s
    assert durations["paused"] - durations["at once"] == pytest.approx(slower, rel=0.25)


@pytest.mark.parametrize(
    "overrides, key",
    [
        ({"tilt_guard_deg": 35.0}, "robot.tilt_guard_deg"),
        ({"tilt_guard_deg": 0.0}, "robot.tilt_guard_deg"),
        ({"guard_retreat": -1.0}, "robot.guard_retreat"),
        ({"guard_pause_s": -0.5}, "robot.guard_pause_s"),
        ({"guard_retreat_speed": 0.0}, "robot.guard_retreat_speed"),
    ],
)
def test_bad_guard_settings_name_their_key(overrides, key):
    with pytest.raises(ConfigError, match=key):
        robot(**overrides)


def test_physics_halt_while_turning_reports_the_way_it_was_turning_to():
    from tests.sim.test_kinematic import slope_world

    rover = robot(tilt_guard_deg=5.0)
    dyn, ctl = make("physics", slope_world(10.0), rover)
    try:
        dyn.reset(np.array([3.0, 0.0]), 0.0)
        start = dyn.state.xy.copy()
        result = dyn.execute(np.array([3.0, 3.0]), ctl)
        assert result.outcome == "halted" and "tilt guard" in result.detail
        # it backed guard_retreat (1.2 m) straight off the spot where the guard tripped, near where it stood
        assert np.hypot(*(dyn.state.xy - start)) == pytest.approx(rover.guard_retreat, abs=0.2)
        trip = result.trace_xy[np.argmax(result.trace_tilt_deg > 5.0)]
        assert np.hypot(*(trip - start)) < 0.1
        ahead = result.hazard_xy - trip
        assert np.hypot(*ahead) == pytest.approx(0.5 * rover.length, abs=0.05)
        assert math.degrees(math.atan2(ahead[1], ahead[0])) == pytest.approx(90.0, abs=5.0)
    finally:
        dyn.close()


@pytest.mark.parametrize("overshoot, outcome", [(0.0, "halted"), (0.3, "halted"), (0.6, "tipover")])
def test_kinematic_guard_overshoot_tips_where_the_ground_steepens_just_past_the_trip(ramp, overshoot, outcome):
    """``dynamics.guard_overshoot``: the rover carries on that far past the guard's trip. On the ramp the tilt
    passes the 30 deg guard about 0.44 m before the 35 deg tip-over limit: 0.3 m stops short of it, 0.6 m not."""
    rover = robot(tilt_guard_deg=30.0)
    cfg = to_object("dynamics", {"name": "kinematic", "guard_overshoot": overshoot})
    dyn, ctl = build(cfg, ramp, rover), TurnThenDrive(cfg.controller, rover)
    dyn.reset(np.array([-2.0, 0.0]), 0.0)
    result = dyn.execute(np.array([6.0, 0.0]), ctl)
    assert result.outcome == outcome
    tilts = result.trace_tilt_deg
    if outcome == "tipover":  # it ends at the first sample over the limit, past the guard's trip
        assert tilts[-1] > rover.tipover_deg and np.all(tilts[:-1] <= rover.tipover_deg)
        assert np.sum(tilts > 30.0) >= 2 and result.failed and result.hazard_xy is None
        assert dyn.state.xy[0] == pytest.approx(result.trace_xy[-1, 0])
    else:
        assert tilts.max() < rover.tipover_deg and dyn.state.tilt_deg < 30.0


def test_guard_overshoot_must_not_be_negative():
    with pytest.raises(ConfigError, match=r"dynamics\.guard_overshoot"):
        to_object("dynamics", {"name": "kinematic", "guard_overshoot": -0.1})
