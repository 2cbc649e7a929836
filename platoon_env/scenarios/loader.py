"""Finding, reading and building scenarios: shipped names, YAML paths, or dicts.

See ``docs/scenarios.md`` (the schema) and ``docs/api.md`` (the public names).

Reading YAML (:func:`read_yaml`) is strict, so that no input escapes the schema's checks:

* **YAML 1.2 scalars.** PyYAML resolves plain scalars by YAML 1.1 rules, where ``1:30`` is the
  sexagesimal integer 90, ``017`` is octal 15, ``1_000`` is 1000 and ``yes``/``no``/``on``/
  ``off`` are booleans. The loader resolves them by the YAML 1.2 core schema instead: integers
  are decimal (``[-+]?[0-9]+``), ``0o17`` or ``0x1f``; floats are ``1.5``, ``1e-3``, ``.inf``,
  ``.nan``; booleans are only ``true``/``false``; dates stay strings. Anything else is a string,
  which the schema then rejects where it expects a number (``followers: 1:30`` is the error
  "expected an integer, got '1:30'").
* **No aliases.** A scenario never needs ``&anchor``/``*alias``; an alias is an error, which
  also refuses alias bombs ("billion laughs") at once, before anything is expanded.
* **Bounded size and depth.** A file (or text) over :data:`MAX_YAML_BYTES` is refused before it
  is parsed, and nesting deeper than :data:`MAX_YAML_DEPTH` is an error (not a RecursionError).
* **No duplicate keys.** A key given twice in one mapping is an error naming the key and both
  lines (PyYAML silently keeps the last one).
* **Safe tags only.** Tags that would build Python objects (``!!python/...``) are rejected,
  never executed; a file must be UTF-8 and may hold no control characters but tab, line feed
  and carriage return (YAML's printable set). Every error is a
  :class:`~platoon_env.config.ScenarioError` naming the file and line.

A scenario (:func:`load_config`) is bounded further, before anything expensive is done with it
(the pure-Python YAML parse costs about 10 s per MiB, the schema and the geometry grow with the
vertices): a scenario file over :data:`MAX_SCENARIO_BYTES` is refused before it is parsed, and
a scenario (a file or a mapping) with more obstacles, vertices or path points than
:data:`MAX_OBSTACLES`, :data:`MAX_POLYGON_VERTICES`, :data:`MAX_WORKSPACE_VERTICES` or
:data:`MAX_PATH_POINTS` is refused before the schema parses it, naming the field and the limit.
The largest shipped scenario file is 6.7 kB (study B; its trajectory file 26.7 kB), and the
largest shipped or procedural layout has 26 obstacles, 171 vertices (one polygon and in all)
and 133 path points: the limits are 38 to 150 times that.

A scenario file (or shipped name) is parsed once per process: the config of its text (and of
the trajectory file it names) is kept, keyed by their SHA-256, so that the envs and episodes of
a run built from one file parse it once; an edited file has another hash and is parsed again.
"""

from __future__ import annotations

import hashlib
import re
from collections import OrderedDict
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from yaml.composer import ComposerError
from yaml.constructor import ConstructorError
from yaml.events import AliasEvent
from yaml.nodes import MappingNode, Node, ScalarNode
from yaml.reader import ReaderError

from platoon_env.config import ScenarioConfig, ScenarioError, field_error
from platoon_env.scenarios.scenario import Scenario, build_scenario
from platoon_env.scenarios.schema import parse_scenario

_DATA = "platoon_env.scenarios.data"

ScenarioLike = str | Path | Mapping[str, Any] | ScenarioConfig | Scenario

#: [bytes] Largest scenario or profile file read (the shipped ones are a few kB; a map of
#: thousands of vertices stays far below this).
MAX_YAML_BYTES = 10 * 1024 * 1024
#: Deepest nesting of YAML collections (a scenario needs about six: blocks, polygons, points).
MAX_YAML_DEPTH = 64
#: [bytes] Largest scenario file: 1 MiB parses in about 10 s (PyYAML in pure Python, measured
#: on a shared 2-core machine); the largest shipped scenario file is 6.7 kB (study B). A long
#: timed trajectory belongs in a ``trajectory_file`` (bounded by :data:`MAX_YAML_BYTES`).
MAX_SCENARIO_BYTES = 1024 * 1024
#: Most polygons in ``workspace.obstacles``, and in ``workspace.free_space.holes`` (shipped and
#: procedural layouts: at most 26).
MAX_OBSTACLES = 1000
#: Most vertices of one polygon: an obstacle, a hole or ``free_space.exterior`` (shipped and
#: procedural: at most 171).
MAX_POLYGON_VERTICES = 10_000
#: Most vertices of the whole workspace, all its polygons together (shipped and procedural: at
#: most 171); the schema's checks and the geometry's cost grow with them.
MAX_WORKSPACE_VERTICES = 20_000
#: Most points of ``leader.path`` (shipped and procedural: at most 133).
MAX_PATH_POINTS = 10_000
#: How many parsed scenario files :func:`load_config` keeps (see the module docstring).
_PARSED_KEPT = 16

# YAML 1.2 core schema (https://yaml.org/spec/1.2.2/#1032-tag-resolution).
_BOOL = "tag:yaml.org,2002:bool"
_INT = "tag:yaml.org,2002:int"
_FLOAT = "tag:yaml.org,2002:float"
_BOOL_RE = re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$")
_INT_RE = re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")
_FLOAT_RE = re.compile(
    r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
    r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
)
# YAML 1.1 resolutions that YAML 1.2 does not have (or resolves differently).
_YAML11_ONLY = {
    _BOOL,
    _INT,
    _FLOAT,
    "tag:yaml.org,2002:timestamp",
    "tag:yaml.org,2002:merge",
    "tag:yaml.org,2002:value",
}


class _ScenarioLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader with YAML 1.2 scalars, no aliases, a depth limit and no duplicate
    keys (see the module docstring)."""

    yaml_implicit_resolvers = {
        first: [(tag, rx) for tag, rx in resolvers if tag not in _YAML11_ONLY]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: Node | None, index: Any) -> Node | None:
        if self.check_event(AliasEvent):
            raise ComposerError(
                None,
                None,
                "found an alias (*name): YAML aliases are not allowed here (write the value out)",
                self.peek_event().start_mark,
            )
        if self._depth >= MAX_YAML_DEPTH:
            raise ComposerError(
                None,
                None,
                f"nested deeper than {MAX_YAML_DEPTH} levels",
                self.peek_event().start_mark,
            )
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: MappingNode, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, MappingNode):
            first_seen: dict[Any, Node] = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                try:
                    first = first_seen.setdefault(key, key_node)
                except TypeError:
                    continue  # an unhashable key: the base class reports it
                if first is not key_node:
                    raise ConstructorError(
                        "while constructing a mapping",
                        node.start_mark,
                        f"found duplicate key {key!r} (first given on line "
                        f"{first.start_mark.line + 1})",
                        key_node.start_mark,
                    )
        return super().construct_mapping(node, deep=deep)  # type: ignore[no-any-return]


def _scalar(loader: _ScenarioLoader, node: Node, pattern: re.Pattern[str], kind: str) -> str:
    if not isinstance(node, ScalarNode):
        raise ConstructorError(None, None, f"expected a scalar {kind}", node.start_mark)
    value = str(loader.construct_scalar(node))
    if not pattern.match(value):
        raise ConstructorError(None, None, f"invalid {kind} {value!r} (YAML 1.2)", node.start_mark)
    return value


def _construct_bool(loader: _ScenarioLoader, node: Node) -> bool:
    return _scalar(loader, node, _BOOL_RE, "boolean").lower() == "true"


def _construct_int(loader: _ScenarioLoader, node: Node) -> int:
    value = _scalar(loader, node, _INT_RE, "integer")
    try:
        if value.startswith("0o"):
            return int(value[2:], 8)
        if value.startswith("0x"):
            return int(value[2:], 16)
        return int(value, 10)
    except ValueError as exc:  # e.g. more digits than Python converts (sys.int_info)
        raise ConstructorError(None, None, f"invalid integer: {exc}", node.start_mark) from exc


def _construct_float(loader: _ScenarioLoader, node: Node) -> float:
    value = _scalar(loader, node, _FLOAT_RE, "float")
    lowered = value.lower()
    if lowered.endswith(".inf"):
        return float("-inf") if lowered.startswith("-") else float("inf")
    if lowered == ".nan":
        return float("nan")
    return float(value)


_ScenarioLoader.add_implicit_resolver(_BOOL, _BOOL_RE, list("tTfF"))
# int before float: "1" matches both patterns, and the first match wins.
_ScenarioLoader.add_implicit_resolver(_INT, _INT_RE, list("-+0123456789"))
_ScenarioLoader.add_implicit_resolver(_FLOAT, _FLOAT_RE, list("-+.0123456789"))
_ScenarioLoader.add_constructor(_BOOL, _construct_bool)
_ScenarioLoader.add_constructor(_INT, _construct_int)
_ScenarioLoader.add_constructor(_FLOAT, _construct_float)


def list_scenarios() -> list[str]:
    """Names of the shipped scenarios (usable wherever a scenario is expected)."""
    names = [
        p.name[: -len(".yaml")]
        for p in resources.files(_DATA).iterdir()
        if p.name.endswith(".yaml")
    ]
    return sorted(names)


def read_yaml(text: str, source: str) -> Any:
    """Load one YAML document strictly (the module docstring lists the rules); every error is a
    :class:`ScenarioError` that names ``source`` and, for a YAML error, the line.

    Tags that would build Python objects are rejected (never executed); aliases, duplicate
    keys, nesting deeper than :data:`MAX_YAML_DEPTH` and text over :data:`MAX_YAML_BYTES` are
    refused; plain scalars resolve by YAML 1.2 rules (``1:30`` is a string, not 90).
    """
    if len(text) > MAX_YAML_BYTES:
        raise ScenarioError(
            f"{source}: {len(text)} characters, more than the limit of {MAX_YAML_BYTES} "
            "(MAX_YAML_BYTES)"
        )
    try:
        # The reader checks the characters as the loader is made: a control character is a
        # ReaderError from here, not from the parse.
        loader = _ScenarioLoader(text)
    except ReaderError as exc:
        raise _unreadable(exc, text, source) from exc
    try:
        return loader.get_single_data()
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{source}:{mark.line + 1}" if mark is not None else source
        problem = getattr(exc, "problem", None) or str(exc)
        raise ScenarioError(f"{where}: malformed YAML: {problem}") from exc
    except RecursionError as exc:  # pragma: no cover - the depth limit comes first
        raise ScenarioError(f"{source}: malformed YAML: nested too deeply") from exc
    finally:
        loader.dispose()


def _unreadable(exc: ReaderError, text: str, source: str) -> ScenarioError:
    """The :class:`ScenarioError` of a character YAML does not allow (a control character,
    say), naming ``source``, the line and the character."""
    line = text.count("\n", 0, exc.position) + 1
    code = exc.character if isinstance(exc.character, int) else ord(exc.character)
    return ScenarioError(
        f"{source}:{line}: malformed YAML: character U+{code:04X} is not allowed (YAML allows "
        "printable characters, tab, line feed and carriage return; no other control character)"
    )


def _read_text(path: Path) -> str:
    """The UTF-8 text of the file at ``path``, refused over :data:`MAX_YAML_BYTES`."""
    size = path.stat().st_size
    if size > MAX_YAML_BYTES:
        raise ScenarioError(
            f"{path}: the file is {size} bytes, more than the limit of {MAX_YAML_BYTES} bytes "
            "(MAX_YAML_BYTES) for a scenario file"
        )
    with path.open("rb") as f:
        raw = f.read(MAX_YAML_BYTES + 1)  # the file may have grown since the stat
    if len(raw) > MAX_YAML_BYTES:
        raise ScenarioError(f"{path}: the file is larger than {MAX_YAML_BYTES} bytes")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise ScenarioError(
            f"{path}:{line}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset "
            f"{exc.start}): save the scenario file as UTF-8"
        ) from exc


#: The key of a leader block that names a trajectory data file (see :func:`_with_trajectory_file`).
TRAJECTORY_FILE = "trajectory_file"


def _trajectory_text(ref: Any, where: str, name: str) -> str:
    """The text of the trajectory file ``ref`` (a :class:`~pathlib.Path` or a package
    resource), read by :func:`_read_text`'s rules."""
    if isinstance(ref, Path):
        if not ref.is_file():
            raise ScenarioError(f"{where}: no such file {ref}")
        return _read_text(ref)
    try:
        text: str = ref.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{where}: cannot read {name!r} ({exc})") from None
    return text


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()


def _with_trajectory_file(
    data: Any, base: Any, source: str, read: list[tuple[Any, str]] | None = None
) -> Any:
    """``data`` with ``leader.trajectory_file`` replaced by the trajectory it names.

    A scenario file may keep a long timed trajectory (a planner's output, a recorded log) in a
    data file: ``leader: {trajectory_file: trajectories/x.yaml}``, a path relative to the
    scenario file's folder (``base``: a :class:`~pathlib.Path` or a package resource), whose
    YAML document is the list ``[[t, x, y, theta], ...]``. The file is read by the same strict
    rules as a scenario file; it may not lie outside ``base`` (no ``..`` or absolute paths).
    A scenario given as a mapping has no folder: it must give ``trajectory`` itself.
    ``read``, if given, collects ``(file, SHA-256 of its text)`` of the file read.
    """
    leader = data.get("leader") if isinstance(data, Mapping) else None
    if not isinstance(leader, Mapping) or TRAJECTORY_FILE not in leader:
        return data
    where = f"{source}: leader.{TRAJECTORY_FILE}"
    name = leader[TRAJECTORY_FILE]
    if "trajectory" in leader:
        raise ScenarioError(f"{where}: give trajectory or trajectory_file, not both")
    if base is None:
        raise ScenarioError(f"{where}: only a scenario file can name a trajectory file")
    if not isinstance(name, str) or not name.strip():
        raise ScenarioError(f"{where}: must be a relative file path, got {name!r}")
    rel = Path(name)
    if rel.is_absolute() or ".." in rel.parts:
        raise ScenarioError(f"{where}: must be a path inside the scenario's folder, got {name!r}")
    ref = base.joinpath(*rel.parts)
    text = _trajectory_text(ref, where, name)
    if read is not None:
        read.append((ref, _digest(text)))
    samples = read_yaml(text, f"{source} -> {name}")
    out = dict(data)
    out["leader"] = {k: v for k, v in leader.items() if k != TRAJECTORY_FILE}
    out["leader"]["trajectory"] = samples
    return out


def _count(value: Any) -> int:
    """How many items a list-like field holds (0 for anything else: the schema reports a
    field of the wrong type)."""
    return len(value) if isinstance(value, list | tuple) else 0


def check_sizes(data: Any, path: str = "scenario") -> None:
    """Refuse a scenario mapping with more obstacles, vertices or path points than the limits
    (:data:`MAX_OBSTACLES`, :data:`MAX_POLYGON_VERTICES`, :data:`MAX_WORKSPACE_VERTICES`,
    :data:`MAX_PATH_POINTS`): a :class:`ScenarioError` naming the field and the limit, before the
    schema parses it. Only counts; every other rule is the schema's."""
    if not isinstance(data, Mapping):
        return
    workspace = data.get("workspace")
    polygons: list[tuple[str, Any]] = []
    if isinstance(workspace, Mapping):
        free = workspace.get("free_space")
        lists = [("obstacles", workspace.get("obstacles"))]
        if isinstance(free, Mapping):
            polygons.append(("free_space.exterior", free.get("exterior")))
            lists.append(("free_space.holes", free.get("holes")))
        for name, items in lists:
            n = _count(items)
            if n > MAX_OBSTACLES:
                raise field_error(
                    f"{path}.workspace.{name}",
                    f"{n} polygons, more than the limit of {MAX_OBSTACLES} (MAX_OBSTACLES)",
                )
            if isinstance(items, list | tuple):
                polygons += [(f"{name}[{i}]", p) for i, p in enumerate(items)]
    total = 0
    for name, polygon in polygons:
        n = _count(polygon)
        if n > MAX_POLYGON_VERTICES:
            raise field_error(
                f"{path}.workspace.{name}",
                f"{n} vertices, more than the limit of {MAX_POLYGON_VERTICES} "
                "(MAX_POLYGON_VERTICES)",
            )
        total += n
        if total > MAX_WORKSPACE_VERTICES:
            raise field_error(
                f"{path}.workspace",
                f"more than {MAX_WORKSPACE_VERTICES} vertices in all its polygons "
                "(MAX_WORKSPACE_VERTICES)",
            )
    leader = data.get("leader")
    n = _count(leader.get("path")) if isinstance(leader, Mapping) else 0
    if n > MAX_PATH_POINTS:
        raise field_error(
            f"{path}.leader.path",
            f"{n} points, more than the limit of {MAX_PATH_POINTS} (MAX_PATH_POINTS)",
        )


#: Parsed scenario texts: (text's SHA-256, folder) -> (config, the trajectory files it read and
#: their SHA-256); at most :data:`_PARSED_KEPT`, the least recently used dropped first.
_PARSED: OrderedDict[tuple[str, str], tuple[ScenarioConfig, tuple[tuple[Any, str], ...]]] = (
    OrderedDict()
)


def _unchanged(read: tuple[tuple[Any, str], ...]) -> bool:
    """Whether each trajectory file of ``read`` still has the text of its SHA-256."""
    try:
        return all(_digest(_trajectory_text(ref, "", str(ref))) == d for ref, d in read)
    except ScenarioError:  # gone or unreadable now: the full parse names the problem
        return False


def _parse_text(text: str, base: Any, source: str, *, name_schema_errors: bool) -> ScenarioConfig:
    """The config of the scenario file text ``text`` (its folder ``base``, named ``source`` in
    errors; the schema's errors too if ``name_schema_errors``): bounded by
    :data:`MAX_SCENARIO_BYTES` and :func:`check_sizes`, parsed once per process (the module
    docstring)."""
    size = len(text.encode("utf-8", "surrogatepass"))
    if size > MAX_SCENARIO_BYTES:
        raise ScenarioError(
            f"{source}: the file is {size} bytes, more than the limit of {MAX_SCENARIO_BYTES} "
            "bytes (MAX_SCENARIO_BYTES) for a scenario file: keep a long leader trajectory in a "
            "trajectory_file"
        )
    key = (_digest(text), str(base))
    kept = _PARSED.get(key)
    if kept is not None and _unchanged(kept[1]):
        _PARSED.move_to_end(key)
        return kept[0]
    data = read_yaml(text, source)
    read: list[tuple[Any, str]] = []
    data = _with_trajectory_file(data, base, source, read)
    try:
        check_sizes(data)
        config = parse_scenario(data)
    except ScenarioError as exc:
        if not name_schema_errors:
            raise
        raise ScenarioError(f"{source}: {exc}") from exc
    _PARSED[key] = (config, tuple(read))
    while len(_PARSED) > _PARSED_KEPT:
        _PARSED.popitem(last=False)
    return config


def _config_from_file(path: Path) -> ScenarioConfig:
    if not path.is_file():
        raise ScenarioError(f"{path}: no such scenario file")
    return _parse_text(_read_text(path), path.parent, str(path), name_schema_errors=True)


def load_config(scenario: ScenarioLike) -> ScenarioConfig:
    """Parse a scenario given as a shipped name, a YAML path or a mapping (not yet built)."""
    if isinstance(scenario, Scenario):
        return scenario.config
    if isinstance(scenario, ScenarioConfig):
        return scenario
    if isinstance(scenario, Mapping):
        check_sizes(scenario)
        return parse_scenario(_with_trajectory_file(scenario, None, "scenario"))
    if isinstance(scenario, (str, Path)):
        text = str(scenario)
        if text in list_scenarios():
            ref = resources.files(_DATA).joinpath(f"{text}.yaml")
            return _parse_text(
                ref.read_text(encoding="utf-8"),
                resources.files(_DATA),
                f"{text}.yaml",
                name_schema_errors=False,
            )
        path = Path(text)
        if path.suffix in (".yaml", ".yml") or path.exists():
            return _config_from_file(path)
        raise ScenarioError(
            f"unknown scenario {text!r}: not a shipped name ({', '.join(list_scenarios())}) "
            "nor a YAML file"
        )
    raise TypeError(f"scenario must be a name, a path or a mapping, got {type(scenario).__name__}")


def load_scenario(scenario: ScenarioLike) -> Scenario:
    """Load, validate and build a fixed scenario from a shipped name, a YAML path or a dict.

    A :class:`Scenario` is returned as is. Raises :class:`ScenarioError` for a procedural
    scenario (a ``generator`` block, e.g. ``procedural_train``): it has no single workspace;
    :func:`platoon_env.scenarios.source.scenario_source` gives its
    :class:`~platoon_env.scenarios.source.ProceduralSource` (``.initial()`` is layout 0,
    ``.sample(rng)`` an episode's layout).
    """
    if isinstance(scenario, Scenario):
        return scenario
    return build_scenario(load_config(scenario))
