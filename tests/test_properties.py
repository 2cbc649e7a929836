"""Property-based families (hypothesis): every command-line value and every scenario input either
parses or is refused with the one error type its caller turns into a message (argparse's
``ArgumentTypeError``: a usage error, exit 2; the loader's ``ScenarioError``), never another
exception (a traceback); and names that become file names never leave their folder."""

from __future__ import annotations

import argparse
import contextlib
import copy
import functools
import io
import json
import math
import re
import time
from typing import Any

import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from experiments.cli import INT64_MAX, count, number
from experiments.policies import REGISTRY, PolicySpec
from experiments.report import MAX_STEM, file_stem
from experiments.studies.evaluate import nest_assignments, parse_assignment
from platoon_env.scenarios.loader import load_config, read_yaml
from platoon_env.scenarios.schema import ScenarioConfig, ScenarioError, config_to_mapping

SETTINGS = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
#: Fewer examples where each one writes and parses a whole scenario file.
FILE_SETTINGS = settings(SETTINGS, max_examples=40)
#: Any text: control characters, surrogates' neighbours, separators, NULs, long runs.
ANY_TEXT = st.text(st.characters(codec="utf-8"), max_size=300)
NUMBERISH = st.one_of(
    ANY_TEXT,
    st.from_regex(r"\A[-+]?[0-9_]{0,12}(\.[0-9_]{0,6})?([eE][-+]?[0-9]{1,4})?\Z"),
    st.sampled_from(["nan", "inf", "-inf", "1e400", "1e-400", "0x10", "١٢", " 5 ", "_", ""]),
)


# ----------------------------------------------------------------------------------------------
# Command-line values
# ----------------------------------------------------------------------------------------------


@SETTINGS
@given(NUMBERISH)
def test_number_is_a_finite_float_or_a_usage_error(text: str) -> None:
    try:
        value = number(text)
    except argparse.ArgumentTypeError as exc:
        assert repr(text) in str(exc)
        return
    assert isinstance(value, float) and math.isfinite(value)


@SETTINGS
@given(st.floats(allow_nan=False, allow_infinity=False))
def test_number_reads_what_python_and_yaml_write(x: float) -> None:
    assert number(repr(x)) == x
    assert number(f"{x:e}") == float(f"{x:e}")


@SETTINGS
@given(NUMBERISH, st.integers(min_value=0, max_value=3))
def test_count_is_a_whole_number_above_its_minimum_or_a_usage_error(text: str, low: int) -> None:
    try:
        value = count(low, "n")(text)
    except argparse.ArgumentTypeError:
        return
    assert isinstance(value, int) and value >= low and value == number(text)


@SETTINGS
@given(st.integers(min_value=-(10**15), max_value=10**15), st.integers(0, 3))
def test_count_reads_every_integer(n: int, low: int) -> None:
    if n >= low:
        assert count(low)(str(n)) == n
    else:
        with pytest.raises(argparse.ArgumentTypeError, match=f">= {low}"):
            count(low)(str(n))


#: Integers as a command line gives them: digits of any length (past int64, past Python's
#: 4,300-digit conversion limit), signs, underscores, exponent forms of integral values.
INTEGERISH = st.one_of(
    NUMBERISH,
    st.from_regex(r"\A[-+]?[0-9]{15,25}\Z"),
    st.integers(4_000, 6_000).map(lambda n: "9" * n),
    st.integers(-(2**70), 2**70).map(str),
    st.integers(-(2**70), 2**70).map(lambda n: f"{n:_}"),
    st.builds(lambda m, e: f"{m}e{e}", st.integers(-99, 99), st.integers(-30, 10**9)),
)


@SETTINGS
@given(INTEGERISH, st.integers(min_value=0, max_value=3))
@example("9" * 5000, 0)  # more digits than int() reads: a ValueError before round 4
@example("9007199254740993", 0)
@example("9007199254740993e0", 0)
def test_count_is_an_exact_int64_or_a_usage_error(text: str, low: int) -> None:
    try:
        value = count(low, "n")(text)
    except argparse.ArgumentTypeError:
        return
    assert type(value) is int and low <= value <= INT64_MAX
    digits = text.strip().replace("_", "")
    if re.fullmatch(r"[+-]?[0-9]+", digits):  # an integer literal: read exactly, not via float
        assert value == int(digits)


@SETTINGS
@given(st.integers(-(2**70), 2**70), st.integers(0, 3))
def test_count_reads_every_int64_exactly_and_refuses_the_rest(n: int, low: int) -> None:
    if low <= n <= INT64_MAX:
        assert count(low)(str(n)) == n
    else:
        with pytest.raises(argparse.ArgumentTypeError, match="must be"):
            count(low)(str(n))


@SETTINGS
@given(INTEGERISH)
@example("1e10000000")  # computed as a 10-million-digit integer before round 4 (minutes)
@example("-1e999999999999")
@example("9" * 5000)
@example("9007199254740993")
@example("9.007199254740993e15")
def test_an_integer_option_is_an_exact_int64_or_a_usage_error(text: str) -> None:
    """platoon-train's integer options (training.train.integer): exact (never a float), at
    most int64 in magnitude, refused at once otherwise."""
    from decimal import Decimal, InvalidOperation

    pytest.importorskip("stable_baselines3")
    from training.train import integer

    start = time.perf_counter()
    try:
        value = integer(text)
    except argparse.ArgumentTypeError as exc:
        assert repr(text)[:40] in str(exc)
        return
    finally:
        assert time.perf_counter() - start < 1.0, f"{text[:40]!r} took too long"
    assert type(value) is int and abs(value) <= INT64_MAX
    try:
        exact = Decimal(text.strip().replace("_", ""))
    except InvalidOperation:  # int() reads what Decimal does not: non-ASCII digits
        return
    assert value == exact


@functools.cache
def _evaluate_seed_type() -> Any:
    """The type of platoon-evaluate's ``--seed`` (as its parser has it)."""
    from experiments.studies.evaluate import build_parser

    return next(a.type for a in build_parser()._actions if a.dest == "seed")


@SETTINGS
@given(INTEGERISH)
@example("9007199254740993")  # stored as ...992 before round 4 (read through float)
@example("9223372036854775808")  # past SQLite's integers: a traceback before round 4
def test_a_seed_option_is_an_exact_seed_or_a_usage_error(text: str) -> None:
    """--seed of platoon-train (a seed of numpy and torch: below 2**32) and of
    platoon-evaluate (an episode seed the store holds: int64): the exact integer given, or a
    usage error (exit 2), never a seed other than the one typed."""
    pytest.importorskip("stable_baselines3")
    from training.config import MAX_SEED
    from training.train import parse_args

    literal = re.fullmatch(r"[+-]?[0-9]+", text.strip().replace("_", "")) is not None
    with contextlib.redirect_stderr(io.StringIO()):
        try:
            cfg = parse_args(["--seed", text])
        except SystemExit as exc:
            assert exc.code == 2
        else:
            assert type(cfg.seed) is int and 0 <= cfg.seed <= MAX_SEED
            if literal:
                assert cfg.seed == int(text.strip().replace("_", ""))
        try:
            seed = _evaluate_seed_type()(text)
        except argparse.ArgumentTypeError:
            return
    assert type(seed) is int and 0 <= seed <= INT64_MAX
    if literal:
        assert seed == int(text.strip().replace("_", ""))


@SETTINGS
@given(
    st.one_of(
        ANY_TEXT,
        st.builds(lambda n, k: f"{n}={k}", ANY_TEXT, st.sampled_from(sorted(REGISTRY))),
        st.builds(lambda n: "x" * n, st.integers(200, 5000)),
    )
)
def test_policy_spec_parse_is_a_spec_or_a_usage_error(text: str) -> None:
    try:
        spec = PolicySpec.parse(text)
    except argparse.ArgumentTypeError as exc:
        assert str(exc)
        return
    assert isinstance(spec, PolicySpec) and spec.name
    if "=" in text and text.split("=", 1)[1] in REGISTRY:
        assert spec.name == text.split("=", 1)[0] and spec.kind == text.split("=", 1)[1]


@SETTINGS
@given(ANY_TEXT)
def test_assignment_is_a_key_path_and_a_value_or_a_usage_error(text: str) -> None:
    try:
        path, value = parse_assignment(text)
    except argparse.ArgumentTypeError as exc:
        assert repr(text) in str(exc)
        return
    assert path and all(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", p) for p in path)
    json.dumps(value)  # a plain value, as a scenario file would give it


KEYS = st.from_regex(r"\A[A-Za-z_][A-Za-z0-9_]{0,8}(\.[A-Za-z_][A-Za-z0-9_]{0,8}){0,2}\Z")
SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**12), 10**12),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=20),
)


@SETTINGS
@given(KEYS, SCALARS)
def test_assignment_values_round_trip(key: str, value: Any) -> None:
    assert parse_assignment(f"{key}={json.dumps(value)}") == (tuple(key.split(".")), value)


@SETTINGS
@given(st.lists(st.tuples(KEYS.map(lambda k: tuple(k.split("."))), SCALARS), max_size=8))
def test_nested_assignments_are_a_mapping_or_a_value_error(items: list[Any]) -> None:
    try:
        nested = nest_assignments(items, "--set")
    except ValueError as exc:
        assert "--set" in str(exc) and "both a value and sub-keys" in str(exc)
        return
    for path, _ in items:  # every assignment's key is in the mapping
        node: Any = nested
        for part in path:
            node = node[part]


@SETTINGS
@given(ANY_TEXT)
def test_file_stem_is_a_plain_name_inside_its_folder(name: str) -> None:
    stem = file_stem(name)
    assert re.fullmatch(r"[A-Za-z0-9_-][A-Za-z0-9_.-]*", stem) and len(stem) <= MAX_STEM
    if re.fullmatch(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,79}", name):
        assert stem == name


@SETTINGS
@given(ANY_TEXT, ANY_TEXT)
def test_distinct_names_are_distinct_files(a: str, b: str) -> None:
    assume(a != b)
    assert file_stem(a) != file_stem(b)


# ----------------------------------------------------------------------------------------------
# Scenario inputs
# ----------------------------------------------------------------------------------------------


@SETTINGS
@given(
    st.one_of(
        ANY_TEXT,
        st.lists(
            st.sampled_from(
                [
                    "a:",
                    " ",
                    "- ",
                    "[",
                    "]",
                    "{",
                    "}",
                    "\n",
                    "!!",
                    "*x",
                    "&x",
                    "\x00",
                    "\x1b",
                    "\t",
                    "1",
                    "'",
                    '"',
                    "#",
                    ":",
                    ",",
                ]
            ),
            max_size=40,
        ).map("".join),
    )
)
def test_yaml_text_is_data_or_a_scenario_error(text: str) -> None:
    try:
        read_yaml(text, "x.yaml")
    except ScenarioError as exc:
        assert str(exc).startswith("x.yaml")


VALUES = st.recursive(
    st.one_of(SCALARS, ANY_TEXT.filter(lambda t: len(t) < 30)),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)
_STUDY_C = config_to_mapping(load_config("study_c"))


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every path into a nested mapping (the leaves and the blocks)."""
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list) and node and not isinstance(node[0], list | float | int):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


PATHS = _paths(_STUDY_C)


def _replaced(path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    """Study C's mapping with the field at ``path`` set to ``value``."""
    data = copy.deepcopy(_STUDY_C)
    node = data
    for part in path[:-1]:
        node = node[part]
    node[path[-1]] = value
    return data


def _check_scenario(data: Any) -> None:
    try:
        cfg = load_config(data)
    except ScenarioError as exc:
        assert str(exc).strip()
        return
    assert isinstance(cfg, ScenarioConfig)


@SETTINGS
@given(st.dictionaries(st.text(max_size=10), VALUES, max_size=6))
def test_a_random_mapping_is_a_scenario_or_a_scenario_error(data: dict[str, Any]) -> None:
    _check_scenario(data)


@SETTINGS
@given(st.sampled_from(PATHS), VALUES)
def test_a_scenario_with_one_field_replaced_is_a_scenario_or_names_the_field(
    path: tuple[Any, ...], value: Any
) -> None:
    try:
        cfg = load_config(_replaced(path, value))
    except ScenarioError as exc:
        named = [str(p) for p in path if isinstance(p, str)]
        assert any(name in str(exc) for name in named), (path, str(exc))
        return
    assert isinstance(cfg, ScenarioConfig)


@FILE_SETTINGS
@given(st.sampled_from(PATHS), st.text(st.characters(codec="utf-8"), max_size=10))
def test_a_scenario_file_with_control_characters_is_a_scenario_error(
    tmp_path_factory: pytest.TempPathFactory, path: tuple[Any, ...], junk: str
) -> None:
    import yaml

    data = _replaced(path, junk)
    file = tmp_path_factory.mktemp("yaml") / "x.yaml"
    file.write_text(yaml.safe_dump(data, allow_unicode=True), encoding="utf-8")
    _check_scenario(str(file))
