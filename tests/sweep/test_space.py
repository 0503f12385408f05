"""Search-space grammar: every form maps to the Optuna distribution a Hydra Optuna-sweeper user expects, and a
sampled value goes back into an override Hydra parses to the same value."""

from __future__ import annotations

import math

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

from diana_lab.sweeps.space import Param, SpaceError, format_value, parse_entry


def _parsed_value(override: str):
    (o,) = OverridesParser.create().parse_overrides([override])
    return o.value()


@pytest.mark.parametrize(
    ("expression", "expected"),
    [
        ("interval(0.1, 5)", FloatDistribution(0.1, 5.0)),
        ("interval(-1, 2.5)", FloatDistribution(-1.0, 2.5)),
        ("tag(log, interval(1e-5, 1e-2))", FloatDistribution(1e-5, 1e-2, log=True)),
        ("int(interval(1, 10))", IntDistribution(1, 10)),
        ("tag(log, int(interval(1, 1000)))", IntDistribution(1, 1000, log=True)),
        ("range(32, 257, 32)", IntDistribution(32, 256, step=32)),  # Hydra's range: the end is excluded
        ("range(1, 5)", IntDistribution(1, 4)),
        ("tag(log, range(1, 100))", IntDistribution(1, 99, log=True)),
        ("range(0.1, 0.5, 0.1)", FloatDistribution(0.1, 0.4, step=0.1)),
        ("choice(64, 128, 256)", CategoricalDistribution((64, 128, 256))),
        ("choice(ppo, sac)", CategoricalDistribution(("ppo", "sac"))),
        ("choice(true, false)", CategoricalDistribution((True, False))),
    ],
)
def test_each_form_maps_to_its_distribution(expression, expected):
    param = parse_entry("algo.x", expression)
    assert isinstance(param, Param)
    assert param.key == "algo.x"
    assert param.distribution == expected


@pytest.mark.parametrize(
    ("expression", "value"),
    [
        ("tag(log, interval(1e-5, 1e-2))", 1.2345678901234567e-4),
        ("int(interval(1, 10))", 7),
        ("choice(64, 128)", 128),
        ("choice(ppo, 'x y')", "x y"),
        ("choice([64,64],[128,128])", "[128,128]"),
        ("choice(true, false)", False),
    ],
)
def test_sampled_value_round_trips_through_an_override(expression, value):
    param = parse_entry("algo.x", expression)
    override = param.override(value)
    parsed = _parsed_value(override)
    if expression.startswith("choice(["):
        assert parsed == [128, 128]
    elif isinstance(value, float):
        assert math.isclose(parsed, value, rel_tol=0, abs_tol=0)  # full precision, not a rounded repr
    else:
        assert parsed == value and type(parsed) is type(value)


@pytest.mark.parametrize(
    ("expression", "ends"),
    [
        ("interval(0.9, 1.5)", (0.9, 1.5)),
        ("range(32, 257, 32)", (32, 256)),  # the last value range(...) yields, not its excluded end
        ("int(interval(1, 10))", (1, 10)),
        ("choice(ppo, sac, a2c)", ("ppo", "sac", "a2c")),
    ],
)
def test_ends_bound_every_value_a_trial_can_get(expression, ends):
    assert parse_entry("algo.x", expression).ends() == ends


def test_fixed_values_stay_overrides():
    assert parse_entry("reward.terms.time.weight", 0.5) == "reward.terms.time.weight=0.5"
    assert parse_entry("a.b", "${c.d}") == "a.b=${c.d}"
    assert parse_entry("+extra.key", "3") == "+extra.key=3"


@pytest.mark.parametrize(
    ("expression", "message"),
    [
        ("interval(5, 1)", "low < high"),
        ("tag(log, interval(0, 1))", "low > 0"),
        ("tag(foo, interval(0, 1))", "unknown tag"),
        ("tag(log, choice(1, 2))", "not to choice"),
        ("interval(0.1", "cannot parse"),
        ("range(5, 1)", "empty"),
        ("shuffle(range(1, 4))", "shuffle"),
        ("choice(1, 1)", "distinct"),
        ("glob(*)", "not supported"),
        ({"low": 1}, "expected one expression"),
    ],
)
def test_bad_expressions_say_what_is_wrong(expression, message):
    with pytest.raises(SpaceError, match=message):
        parse_entry("algo.x", expression)


def test_searched_key_takes_no_prefix():
    with pytest.raises(SpaceError, match="prefix"):
        parse_entry("+algo.x", "interval(0, 1)")


def test_format_value_quotes_only_what_hydra_would_misread():
    assert format_value("ppo") == "ppo"
    assert format_value("a b") == "'a b'"
    assert format_value("true") == "'true'"
    assert format_value(1e-5) == "1e-05"
    assert format_value([1, 2]) == "[1,2]"
    quoted = format_value("it's")
    assert _parsed_value(f"k={quoted}") == "it's"
