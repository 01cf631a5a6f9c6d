"""ROS 2 parameters files (`--params-file`), read safely and matched to a node the way rcl does, for the
CLI's `replay --params-file` and the node alike.

Reading (`read_params_file`): a regular file of at most MAX_PARAMS_FILE_BYTES, UTF-8, YAML without
aliases and nested at most MAX_YAML_DEPTH deep: a FIFO, a 50 MB file, 100,000-deep nesting or binary
content is one line, never a hang or a traceback. The node can call it before rclpy parses the file.

Matching (`node_parameters`), as rcl's YAML parser and rclpy apply a file (checked against rclpy on
Jazzy): each top-level key names nodes by their fully qualified name, a leading '/' added when missing
(`accel_calibration` is `/accel_calibration`, `"*"` is `/*`); a `*` token stands for exactly one name
token, a `**` token for any number (none included), so `/**` is every node, `/*` every node of the root
namespace and `/uav1/*` every node of /uav1. Every matching block applies; where two set the same
parameter, the block whose name comes later in the file wins (blocks of the same name are merged at
the place of the first). Each block holds `ros__parameters:`; nested mappings become dotted names.
"""
from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..core.errors import SettingsError
from .calibration_file import read_regular_file, safe_yaml_load

MAX_PARAMS_FILE_BYTES = 1 << 20  # the package's own file is ~3 KB
DEFAULT_NODE = "/accel_calibration"
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*|\*|\*\*")


def read_params_file(path: str | os.PathLike[str], what: str = "--params-file",
                     error: type[Exception] = SettingsError) -> Any:
    """The parsed YAML document of a parameters file, or one `error` line naming it (see the module)."""
    raw = read_regular_file(path, MAX_PARAMS_FILE_BYTES, f"{what} (a ROS 2 parameters YAML)", error=error)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise error(f"{what} {path}: not a text file (not UTF-8)") from None
    return safe_yaml_load(text, f"{what} {path}", error=error)


def fully_qualified(namespace: str, node_name: str = DEFAULT_NODE.lstrip("/")) -> str:
    """/namespace/node_name, as rcl_node_get_fully_qualified_name gives it."""
    namespace = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{namespace}/{node_name.strip('/')}"


def _pattern_tokens(key: str, source: str) -> list[str]:
    """The tokens of a block's node name as rcl reads it (leading '/' added), or a SettingsError for a name
    rcl refuses (a '*' inside a token, an empty token, a trailing '/')."""
    name = key if key.startswith("/") else "/" + key
    tokens = name[1:].split("/")
    if not all(_TOKEN.fullmatch(token) for token in tokens):
        raise SettingsError(f"{source}: block {key[:80]!r} is not a node name rcl accepts (tokens of letters, "
                            "digits and '_', or a whole '*' or '**')")
    return tokens


def _matches(pattern: list[str], name: list[str]) -> bool:
    """Whether a node name's tokens match a pattern's: '*' one token, '**' any number of them. Linear in
    each (a table of which name prefixes the pattern so far matches), whatever the '**'s."""
    reached = [True] + [False] * len(name)  # reached[j]: the pattern so far matches name[:j]
    for token in pattern:
        if token == "**":
            reached = [any(reached[:j + 1]) for j in range(len(name) + 1)]
        else:
            reached = [False] + [reached[j] and token in ("*", name[j]) for j in range(len(name))]
    return reached[-1]


def node_parameters(document: Any, node_fqn: str = DEFAULT_NODE, source: str = "params file") -> dict[str, Any]:
    """{dotted parameter name: value} that a parameters file gives the node of fully qualified name
    `node_fqn` (e.g. /uav1/accel_calibration), by rcl's rules (see the module). A SettingsError (one line)
    when the document is not a parameters file or no block names this node."""
    if not isinstance(document, dict):
        raise SettingsError(f"{source}: not a ROS 2 parameters file (expected a mapping of node names)")
    name = node_fqn.strip("/").split("/")
    merged: dict[str, dict[str, Any]] = {}  # rcl's order: a node name where it first appears
    for key, block in document.items():
        key_text = str(key)
        if not isinstance(block, dict) or not isinstance(block.get("ros__parameters"), dict):
            raise SettingsError(f"{source}: block {key_text[:80]!r} has no 'ros__parameters:' mapping")
        tokens = _pattern_tokens(key_text, source)
        merged.setdefault("/" + "/".join(tokens), {}).update(_flatten(block["ros__parameters"]))
    values: dict[str, Any] = {}
    matched = False
    for pattern, parameters in merged.items():
        if _matches(pattern[1:].split("/"), name):
            values.update(parameters)
            matched = True
    if not matched:
        raise SettingsError(f"{source}: no block for node {node_fqn} (blocks: "
                            f"{', '.join(merged)[:120] or 'none'}); name it, or use '/**:' for every node")
    return values


def params_file_parameters(path: str | os.PathLike[str], node_fqn: str = DEFAULT_NODE, what: str = "--params-file",
                           error: type[Exception] = SettingsError) -> dict[str, Any]:
    """read_params_file, then node_parameters: what a parameters file gives the node `node_fqn`."""
    document = read_params_file(path, what, error)
    try:
        return node_parameters(document, node_fqn, source=f"{what} {Path(path)}")
    except SettingsError as problem:
        raise error(str(problem)) from None


def _flatten(mapping: Mapping[Any, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, name + "."))
        else:
            out[name] = value
    return out
