"""The reported target: on the Mars yard (Jackal, kinematic, 100 episodes) the A* oracle succeeds >= 95 %,
the straight line measurably less (tip-overs and stalls on the hill and crater walls)."""

import pytest

from diana_lab.config import compose
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.evaluation import AStarOracle, EvalConfig, StraightLine, make_suite, run_suite, summarize


@pytest.mark.slow
def test_astar_beats_straight_on_the_mars_yard():
    env = RoverNavEnv(config=compose(["world=mars_yard", "robot=jackal", "dynamics=kinematic"]))
    try:
        c = EvalConfig()
        suite = make_suite(env, c.episodes, c.seed, c.min_distance, c.max_distance)
        astar = summarize(run_suite(AStarOracle(), env, suite))
        straight = summarize(run_suite(StraightLine(), env, suite))
    finally:
        env.close()
    assert astar["success_rate"] >= 0.95, astar
    assert straight["success_rate"] <= astar["success_rate"] - 0.2, straight
    assert straight["tipover_rate"] + straight["stuck_rate"] >= 0.2
    assert astar["spl"] > straight["spl"]
