"""The registry of rule kinds (rbx.rules): every kind has every facet, every rule dataclass of rbx.model has a
record, the kernels' walk calls every inner kind's step, and each facet answers for its kind's example — the
config reads it and writes it back the same, the titles name it (never "?"), the precise loop and the reference
loop take it. A kind added without one of these fails here.
"""
import dataclasses
import inspect

import numpy as np
import pytest

import rbx
from rbx import analysis, config, model, rules
from tests import reference

FACETS = ("name", "model", "code", "parse", "plain", "node", "step", "precise", "precise_step", "phrase", "example")
#: facets only inner kinds (with children) have
INNER = ("step", "precise_step")


def _rule_classes():
    """The rule dataclasses of rbx.model: every frozen dataclass a rule tree is made of."""
    return [model.Constant, model.Hemisphere, model.Random, model.Exit]


def test_every_kind_has_every_facet():
    assert set(rules.RULE_KINDS) == {"constant", "hemisphere", "random", "exit"}
    for name, kind in rules.RULE_KINDS.items():
        for facet in FACETS:
            value = getattr(kind, facet, None)
            if facet in INNER and kind.leaf:
                continue
            assert value is not None, (name, facet)
            if facet not in ("name", "model", "code", "example"):
                assert callable(value), (name, facet)
        assert kind.name == name
    codes = [k.code for k in rules.RULE_KINDS.values()]
    assert sorted(codes) == list(range(len(codes)))        # node kinds are distinct small integers


def test_every_rule_class_has_a_record():
    for cls in _rule_classes():
        assert rules.kind_of(cls.__new__(cls)).model is cls
    assert {k.model for k in rules.RULE_KINDS.values()} == set(_rule_classes())


def test_choose_calls_every_inner_step():
    source = inspect.getsource(rules.choose.py_func)
    for kind in rules.RULE_KINDS.values():
        if not kind.leaf:
            assert kind.step.__name__ + "(" in source, kind.name
            assert getattr(rules, kind.name.upper()) == kind.code and f"== {kind.name.upper()}" in source


def _load(rule, n=2, table=None):
    table = table or ({"kind": "strip", "width": 1.0} if n == 2 else {"kind": "plates", "gap": 1.0})
    state = ({"position": [0.3, 0.2], "velocity": [0.6, 0.8], "angular_velocity": 1.0} if n == 2 else
             {"position": [0.0, 0.0, 0.5], "velocity": [0.6, 0.0, 0.8], "angular_velocity": [0.0, 0.0, 1.0]})
    return rbx.load({"table": table, "boundary": {"default": rule}, "ball": {"radius": 0.1, "inertia": "uniform"},
                     "initial": state, "run": {"collisions": 20, "trajectories": 1, "seed": 1},
                     "output": {"record": ["time", "rank"]}})


@pytest.mark.parametrize("name", ["constant", "hemisphere", "random", "exit"])
def test_each_kind_parses_writes_back_and_is_named(name):
    example = rules.RULE_KINDS[name].example
    exp = _load(example)
    rule = exp.wall_rules[0]
    assert rules.kind_of(rule).name == name
    assert config.rule_config(rule) == example                 # the plain form is the config it was read from
    assert exp.replace(wall_rules=exp.wall_rules).wall_rules == exp.wall_rules
    phrase = analysis.describe_rule(rule, 2)
    assert phrase and "?" not in phrase


@pytest.mark.parametrize("name", ["constant", "hemisphere", "random", "exit"])
def test_each_kind_runs_in_the_precise_and_the_reference_loop(name):
    """The precise loop (its mpmath form and step) and tests/reference.py take the kind, and agree with the
    engine on the rank at every collision."""
    from rbx.precise import precise_run
    from rbx.rng import PURPOSE_RULES, uniforms
    from rbx.simulation import run_in_memory
    # (a hole ends the run at its first contact, on the rectangle: a loop that the exit tests compile too)
    exp = _load(rules.RULE_KINDS[name].example, table={"kind": "rectangle", "width": 2.0, "height": 1.0}
                if name == "exit" else None)
    records, count, _ = run_in_memory(exp)
    T = int(count[0])
    ranks = records["rank"][0, :T]
    assert T == (2 if name == "exit" else 21)
    prec, pcount = precise_run(exp, collisions=20, digits=30)
    assert pcount == T
    np.testing.assert_array_equal(prec["rank"][:T], ranks)
    draws = uniforms(exp.run.seed, 0, PURPOSE_RULES, 0, 100)
    ref = reference.reference_run(exp.resolved, uniforms=draws, collisions=20)
    assert [r["rank"] for r in ref] == list(ranks)


def test_a_kind_without_a_record_is_refused_by_name():
    @dataclasses.dataclass(frozen=True)
    class Spiral:
        turns: int
    with pytest.raises(rules.NotARule):
        rules.describe(Spiral(2), 2)                          # the titles answered "?" for an unknown kind
    with pytest.raises(rbx.ConfigError) as info:
        config.rule_config(model.Hemisphere((0.0, 1.0), model.Constant(1), Spiral(2)))
    assert info.value.key == "rule.smooth"


def test_the_config_names_the_registered_kinds():
    with pytest.raises(rbx.ConfigError) as info:
        _load({"rule": "spiral"})
    assert "unknown rule 'spiral'" in info.value.problem
    with pytest.raises(rbx.ConfigError) as info:
        _load({"probabilities": [1.0]})
    assert info.value.problem == "missing required key (one of: constant, hemisphere, random, exit)"
