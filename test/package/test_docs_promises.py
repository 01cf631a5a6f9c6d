"""What the README and docs/ say is what the code does: every promise is a test.

- Every `accel-calib` command and flag the README's command reference lists exists, with the choices it
  lists; every option a command has is in the reference.
- Every code path the docs name (`core/fit_outliers.critical_ratio`, `accel_calibration.io.history`,
  `bag/corrected_copy.py`, `test/test_x.py::test_y`, a bare `units.py`) exists as written.
- Every `--flag` the docs give an `accel-calib` command exists.
- The README's node section: topics, their types, the services and their types as the node creates them;
  the parameter defaults it quotes as the node declares them; the launch arguments it names.
- The command-line defaults the README and docs quote, the Python API the README shows, and its calibration
  file's keys as `save_calibration` writes them.
- docs/node.md: every parameter named, which change at run time, its table the README's; every parameter
  default any doc quotes (`name` (value)); the constants the docs quote (buffer sizes, QoS depths, gates).
- docs/models.md's Python examples run as written and calibrate.
- Promises that had no test: `compare` of an identity calibration against the ArduPilot log (327.6 mg), an
  mcap chunk of the wrong declared size (one line), what building the parser imports.
docs/promises.md maps the README's other promises to the tests that assert them; its references are
checked here like any other.

Test references are resolved by file name anywhere under test/ (files may move into test/<layer>/)."""
from __future__ import annotations

import argparse
import ast
import importlib
import re
from pathlib import Path

import numpy as np
import pytest

REPO = next(p for p in Path(__file__).resolve().parents if (p / "README.md").exists() and (p / "docs").is_dir())
README = REPO / "README.md"
DOCS = sorted((REPO / "docs").glob("*.md"))
# The README is the user's short document (about 15 KB: read in one sitting); detail goes to docs/, so a
# README that grows past this is a sign something belongs in docs/.
README_MAX_BYTES = 15_500


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    from accel_calibration.cli.main import _parser

    (action,) = [a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


def _options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {flag: action for action in parser._actions for flag in action.option_strings
            if action.dest != "help"}


# --- the README's command reference --------------------------------------------------------------------

def _reference_block() -> dict[str, str]:
    """{command: its lines in docs/cli.md's command-reference code block (the README links to it)."""
    section = _text(REPO / "docs" / "cli.md").split("## Command reference", 1)[1].split("\n## ", 1)[0]
    block = section.split("```", 2)[1]
    commands: dict[str, str] = {}
    current = None
    for line in block.splitlines():
        match = re.match(r"accel-calib (\w+)", line)
        if match:
            current = match.group(1)
            commands[current] = commands.get(current, "") + line
        elif current:
            commands[current] += " " + line
    return commands


def test_the_readme_is_a_users_document_of_about_15_kb():
    assert len(README.read_bytes()) <= README_MAX_BYTES


def test_the_command_reference_lists_every_command_with_every_flag_and_choice_it_has():
    reference = _reference_block()
    parsers = _subparsers()
    assert sorted(reference) == sorted(parsers), "commands in the README's reference != accel-calib's"
    for command, line in reference.items():
        options = _options(parsers[command])
        listed = set(re.findall(r"(?<![\w-])(--?[a-zA-Z][\w-]*)", line))
        assert sorted(listed - set(options)) == [], f"{command}: the README lists flags it does not have"
        for action in {id(a): a for a in options.values()}.values():
            assert set(action.option_strings) & listed, f"{command}: {action.option_strings} missing from README"
        for flag, choices in re.findall(r"(--[\w-]+) ([\w-]+(?:\|[\w-]+)+)", line):
            assert set(choices.split("|")) == set(options[flag].choices or ()), f"{command} {flag}: choices"


def test_every_command_answers_help_in_one_process(capsys):
    from accel_calibration.cli.main import main

    for command in _subparsers():
        with pytest.raises(SystemExit) as stop:
            main([command, "--help"])
        assert stop.value.code == 0
        assert f"accel-calib {command}" in capsys.readouterr().out


# The command-line defaults the README's and docs' prose quote: (doc, command, flag, its words, the default).
CLI_DEFAULTS = [
    ("README.md", "replay", "--armed-margin-s", "`--armed-margin-s` (2 s)", 2.0),
    ("README.md", "fleet", "--history", "(default `calibrations.sqlite`)", "calibrations.sqlite"),
    ("README.md", "history", "--k-sigma", "(`--k-sigma`, 5)", 5.0),
    ("README.md", "history", "--max-bias-change", "beyond 50 mg of bias", 50.0),
    ("README.md", "history", "--max-scale-change", "1 % of scale", 0.01),
    ("README.md", "export", "--max-loss-mg", "`--max-loss-mg`, 2 mg at 1 g", 2.0),
    ("docs/cli.md", "export", "--max-loss-mg", "`--max-loss-mg`, 2 mg at 1 g", 2.0),
    ("README.md", "fit", "--model", "`sphere9` (default;", "sphere9"),
    ("docs/cli.md", "fit", "--model", "`sphere9` (default;", "sphere9"),
    ("docs/replay.md", "replay", "--armed-margin-s", "`--armed-margin-s` (default 2 s", 2.0),
    ("docs/exports.md", "export", "--max-loss-mg", "`--max-loss-mg` (default 2)", 2.0),
    ("docs/fleet.md", "history", "--k-sigma", "k = 5 by default (`--k-sigma`)", 5.0),
    ("docs/fleet.md", "history", "--max-bias-change", "50 mg of bias (`--max-bias-change`)", 50.0),
    ("docs/fleet.md", "history", "--max-scale-change", "1 % of scale (`--max-scale-change`)", 0.01),
    ("docs/fleet.md", "report", "--k-sigma", "k = 5 by default (`--k-sigma`)", 5.0),
]


@pytest.mark.parametrize("doc, command, flag, words, default", CLI_DEFAULTS,
                         ids=[f"{d} {c} {f}" for d, c, f, *_ in CLI_DEFAULTS])
def test_the_command_line_defaults_the_docs_quote_are_the_parsers(doc, command, flag, words, default):
    assert words in re.sub(r"\s+", " ", _text(REPO / doc))
    assert _options(_subparsers()[command])[flag].default == default


def test_the_python_api_the_readme_shows_imports():
    import accel_calibration

    line = re.search(r"From Python: `(from accel_calibration import [^`]+)`", _text(README)).group(1)
    for name in line.split(" import ", 1)[1].split(","):
        assert callable(getattr(accel_calibration, name.strip())), name


# --- code named in the docs ----------------------------------------------------------------------------

# Names in backticks that look like code but are something else: YAML keys, attributes of results,
# parameters, files of other projects, example file names.
NOT_CODE = re.compile(
    r"^(calibration\.(bias|matrix|poses|residual_rms_mg)|result\.\w+|static\.\w+|temperature\.\w+|"
    r"vehicle_\w+\.\w+|scipy\.\w+(\.\w+)?|numpy\.\w+|rclpy\.\w+|dividing_head\.\w+|imu\.yaml|"
    r"\w+\.(yaml|ulg|csv|sqlite|BIN|bin|png|mcap|db3|txt|xml|cpp|h|launch\.py)|.*/(test\.BIN|calibration\.cpp)|"
    r"include/.*|src/.*)$")
SEARCH_DIRS = ("accel_calibration", "test", "bench", "msg_tools", "launch")


def _defines(path: Path, name: str) -> bool:
    tree = ast.parse(_text(path))
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.name == name:
            return True
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(isinstance(t, ast.Name) and t.id == name for t in targets):
                return True
    return False


def _files_named(name: str) -> list[Path]:
    return [p for folder in SEARCH_DIRS for p in (REPO / folder).rglob(name) if ".venv" not in p.parts]


def _resolve_module_attribute(module: str, attributes: list[str]) -> str | None:
    """None when `module` imports and holds the attribute chain, else why not."""
    try:
        target = importlib.import_module(module)
    except ImportError as error:
        return f"cannot import {module}: {error}"
    for index, attribute in enumerate(attributes):
        if attribute == "*":
            return None
        if not hasattr(target, attribute):
            # `session.live_feed`: a method of the module's class, named as the docs' readers hold it
            if index == 0 and any(isinstance(value, type) and value.__module__ == module and hasattr(value, attribute)
                                  for value in vars(target).values()):
                return None
            return f"{module} has no {'.'.join(attributes)}"
        target = getattr(target, attribute)
    return None


def _problem(reference: str) -> str | None:
    """Why `reference` (the text of one backticked span) names no code that exists, or None."""
    if NOT_CODE.match(reference):
        return None
    # test/test_x.py::test_y, bench/bench_x.py, msg_tools/x.py: a file under those folders (any depth)
    match = re.fullmatch(r"(test|bench|msg_tools|launch|config)/([\w/]*?)(\w+\.(?:py|yaml))(?:::(\w+))?", reference)
    if match:
        found = _files_named(match.group(3)) if match.group(1) == "test" else \
            [REPO / match.group(1) / match.group(2) / match.group(3)]
        found = [p for p in found if p.exists()]
        if not found:
            return f"no file {reference}"
        if match.group(4) and not any(_defines(p, match.group(4)) for p in found):
            return f"{match.group(3)} defines no {match.group(4)}"
        return None
    # test_x.py::test_y (the way the docs cite a test: by file and test name, wherever the file lives)
    match = re.fullmatch(r"((?:test|conftest|session_doors)\w*\.py)(?:::(\w+))?", reference)
    if match:
        found = _files_named(match.group(1))
        if not found:
            return f"no file {match.group(1)} under test/"
        if match.group(2) and not any(_defines(p, match.group(2)) for p in found):
            return f"{match.group(1)} defines no {match.group(2)}"
        return None
    # test_x.Name: a helper of a test module
    match = re.fullmatch(r"(test_\w+)\.(?!py$)(\w+)", reference)
    if match:
        found = _files_named(match.group(1) + ".py")
        return None if any(_defines(p, match.group(2)) for p in found) else f"no {reference} under test/"
    # core/fit.py, cli/replay.*, io/history.History.write, accel_calibration.io.history
    match = re.fullmatch(r"(?:accel_calibration[./])?(core|io|live|bag|ros|cli)[./](\w+)(\.py)?((?:\.(?:\w+|\*))*)",
                         reference)
    if match:
        module = f"accel_calibration.{match.group(1)}.{match.group(2)}"
        if not (REPO / "accel_calibration" / match.group(1) / f"{match.group(2)}.py").exists():
            return f"no module {module}"
        attributes = [a for a in match.group(4).split(".") if a]
        return _resolve_module_attribute(module, attributes) if attributes else None
    # units.py, gauss_newton.py: a file of the package (or of the test helpers, benchmarks)
    match = re.fullmatch(r"(\w+)\.py", reference)
    if match:
        return None if _files_named(reference) else f"no file {reference} in {SEARCH_DIRS}"
    # fit_outliers.critical_ratio, bag_io.JAZZY_DEFINITIONS: a module of the package by its file name
    match = re.fullmatch(r"(\w+)\.(\w+(?:\.\w+)*)", reference)
    if match:
        modules = [p for p in (REPO / "accel_calibration").rglob(f"{match.group(1)}.py")]
        if not modules:
            return None  # not a module of ours: an attribute or key of something else
        problems = [_resolve_module_attribute(
            "accel_calibration." + ".".join(p.relative_to(REPO / "accel_calibration").with_suffix("").parts),
            match.group(2).split(".")) for p in modules]
        return None if None in problems else problems[0]
    return None


def _code_references() -> list[tuple[str, str]]:
    references = []
    for path in [README, *DOCS]:
        for span in re.findall(r"`([^`\n]+)`", _text(path)):
            for word in re.split(r"[\s,()]+", span):
                word = word.strip(".:;")
                if re.search(r"[./]", word) and re.fullmatch(r"[\w./:*]+", word) and not word.startswith("/"):
                    references.append((path.name, word))
    return sorted(set(references))


def test_every_code_path_the_docs_name_exists():
    problems = [f"{name}: `{reference}`: {problem}" for name, reference in _code_references()
                if (problem := _problem(reference))]
    assert problems == []


def test_the_reference_resolver_refuses_what_does_not_exist():
    assert _problem("cli/main._replay_one") is not None
    assert _problem("bag/bag_io.write_corrected") is not None
    assert _problem("test/test_cli.py::no_such_test") is not None
    assert _problem("test_cli.py::no_such_test") is not None
    assert _problem("test_no_such_file.py") is not None
    assert _problem("test_cli.py::test_fit_then_apply_as_a_user_would") is None
    assert _problem("no_such_module.py") is not None
    assert _problem("bag/corrected_bag.write_corrected") is None
    assert _problem("test/test_docs_promises.py::test_every_code_path_the_docs_name_exists") is None


# Flags of other tools the docs quote (ros2, colcon, pytest, make).
OTHER_TOOLS_FLAGS = {"--ros-args", "--params-file", "--symlink-install", "--packages-select", "--pytest-args",
                     "--from-paths", "--ignore-src", "--system-site-packages", "--verbose", "--collect-only"}


def _command_lines(text: str) -> list[str]:
    """Each `accel-calib CMD ...` of a text: in a code block the line (and the indented lines of options
    continuing it), in prose a backticked span, else the command's name alone."""
    commands: list[str] = []
    prose: list[str] = []
    in_block = continuing = False
    for line in text.splitlines():
        if line.startswith("```"):
            in_block, continuing = not in_block, False
            continue
        if not in_block:
            prose.append(line)
            continue
        code = line.split(" #", 1)[0]
        if continuing and code.startswith(" ") and code.lstrip().startswith(("[", "-", "(")):
            commands[-1] += " " + code
            continue
        continuing = "accel-calib " in code
        if continuing:
            commands.append(code.split("accel-calib ", 1)[1])
    for paragraph in "\n".join(prose).split("\n\n"):
        spans = re.findall(r"`([^`]+)`", paragraph)
        commands += [" ".join(span.split("accel-calib ", 1)[1].split()) for span in spans if "accel-calib " in span]
        outside = re.sub(r"`[^`]+`", "", paragraph)
        commands += re.findall(r"accel-calib (\w+)", outside)
    return [c for c in commands if c.strip()]


def test_every_accel_calib_flag_the_docs_give_exists():
    """A `--flag` written in an `accel-calib CMD ...` example exists for CMD, and takes the choices listed."""
    from accel_calibration.cli.main import _parser

    parsers = _subparsers()
    top_flags = _options(_parser())  # `accel-calib --version`
    problems = []
    for path in [README, *DOCS]:
        for line in _command_lines(_text(path)):
            command = line.split()[0]
            if command.startswith("--"):
                if command not in top_flags:
                    problems.append(f"{path.name}: accel-calib has no {command}")
                continue
            if command not in parsers:
                if command not in ("CMD", "error", "interrupted"):
                    problems.append(f"{path.name}: no command {command}: {line.strip()}")
                continue
            options = _options(parsers[command])
            for flag in re.findall(r"(?<![\w-])(--[a-zA-Z][\w-]*)", line):
                if flag not in options and flag not in OTHER_TOOLS_FLAGS:
                    problems.append(f"{path.name}: accel-calib {command} has no {flag}")
            for flag, choices in re.findall(r"(--[\w-]+) ([\w-]+(?:\|[\w-]+)+)", line):
                if flag in options and not set(choices.split("|")) <= set(options[flag].choices or ()):
                    problems.append(f"{path.name}: accel-calib {command} {flag} takes {options[flag].choices}, "
                                    f"the doc says {choices}")
    assert problems == []


# --- the README's node section -------------------------------------------------------------------------

def _node_section() -> str:
    return _text(README).split("## The live node", 1)[1].split("\n## ", 1)[0]


def _readme_interface_table() -> list[tuple[str, list[str], str]]:
    return _interface_table(_node_section())


def _interface_table(text: str) -> list[tuple[str, list[str], str]]:
    """(in/out/service, [names], type) per row of a node table."""
    rows = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0] in ("in", "out", "service"):
            names = re.findall(r"`([\w/]+)`", cells[1])
            if cells[0] == "service":
                kind = re.search(r"\((\w+)\)", cells[1]).group(1)
            else:
                kind = re.match(r"([\w/]+)", cells[2]).group(1) if "/" in cells[2].split(" ")[0] else ""
            rows.append((cells[0], names, kind))
    return rows


RCLPY_SERVICES = re.compile(r"/(describe_parameters|get_parameters|get_parameter_types|list_parameters|"
                            r"set_parameters|set_parameters_atomically|get_type_description)$")


@pytest.mark.ros
def test_the_readme_node_table_is_what_the_node_creates(ros, tmp_path):
    """Topics, types and services as the node creates them (in this process, no DDS discovery)."""
    from rclpy.parameter import Parameter

    from accel_calibration.ros.node import CalibrationNode

    node = CalibrationNode(parameter_overrides=[Parameter("calibration_file", value=str(tmp_path / "c.yaml"))])
    try:
        def type_name(cls) -> str:
            module = cls.__module__.split(".")
            return f"{module[0]}/{cls.__name__}"

        created = {"in": {s.topic_name.lstrip("/"): type_name(s.msg_type) for s in node.subscriptions},
                   "out": {p.topic_name.lstrip("/"): type_name(p.msg_type) for p in node.publishers
                           if p.topic_name not in ("/rosout", "/parameter_events")},
                   "service": {s.srv_name.lstrip("/"): s.srv_type.__name__ for s in node.services
                               if not RCLPY_SERVICES.search(s.srv_name)}}
        listed: dict[str, dict[str, str]] = {"in": {}, "out": {}, "service": {}}
        for kind, names, type_ in _readme_interface_table():
            for name in names:
                listed[kind][name.lstrip("/")] = type_
        assert listed["service"] == created["service"]
        assert set(listed["in"]) == set(created["in"]) and set(listed["out"]) == set(created["out"])
        for kind in ("in", "out"):
            for name, type_ in listed[kind].items():
                assert created[kind][name] == type_.replace("/msg/", "/"), name
        (imu,) = [s for s in node.subscriptions if s.topic_name == "/imu/data_raw"]
        depth = imu.qos_profile.depth
        assert f"best effort, depth {depth}" in _node_section()
        assert imu.qos_profile.reliability.name == "BEST_EFFORT" and depth >= 50
    finally:
        node.close()
        node.destroy_node()


def test_the_parameter_defaults_the_readme_quotes_are_the_declared_ones():
    from accel_calibration.core.settings import PARAMETERS
    from accel_calibration.ros.parameters import NODE_PARAMETERS

    declared = {p.name: p for p in PARAMETERS + NODE_PARAMETERS}
    paragraph = _node_section().split("Parameters:", 1)[1].split("\n\n", 1)[0]
    quoted = re.findall(r"`([\w.]+)` \(((?:[^()]|\([^()]*\))*)\)", paragraph)
    assert len(quoted) >= 6, paragraph
    for name, words in quoted:
        parameter = declared[name]
        if name == "calibration_file":
            assert parameter.default == "" and "~/.ros/accel_calibration/<namespace>/<node" in parameter.description
            assert "~/.ros/accel_calibration/<namespace>/<node>.yaml" in words
            continue
        values = re.findall(r"`([^`]+)`", words)
        if " or " in words:  # `sphere9` or `six`: the default first, then the other choices
            assert values[0] == parameter.default and set(values) == set(parameter.choices), name
            continue
        first = (values[0] if values else words).split()[0]
        value = {"false": False, "true": True}.get(first, first)
        if isinstance(parameter.default, (int, float)) and not isinstance(parameter.default, bool):
            value = float(value)
        assert value == parameter.default, name
    calibrating = re.sub(r"\s+", " ", _node_section())
    assert "at least 12 different orientations (`min_poses`)" in calibrating and declared["min_poses"].default == 12


def test_the_launch_arguments_the_readme_and_node_md_name_exist():
    source = _text(REPO / "launch" / "calibration.launch.py")
    declared = set(re.findall(r'DeclareLaunchArgument\(\s*"(\w+)"', source))
    section = _node_section()
    named = set(re.findall(r"(\w+):=", section.split("Launch:", 1)[1].split("\n\n", 1)[0]))
    named |= set(re.findall(r"`(\w+)`", section.split("(also", 1)[1].split(")", 1)[0]))
    assert named and named <= declared, named - declared
    node_doc = re.sub(r"\s+", " ", _text(REPO / "docs" / "node.md"))
    arguments = node_doc.split("Arguments: ", 1)[1].split(". ", 1)[0]
    assert set(re.findall(r"`(\w+)`", arguments)) == declared, "docs/node.md's launch arguments"


def _declared_parameters() -> dict:
    from accel_calibration.core.settings import PARAMETERS
    from accel_calibration.ros.parameters import NODE_PARAMETERS

    return {p.name: p for p in PARAMETERS + NODE_PARAMETERS}


def test_every_parameter_default_the_docs_quote_is_the_declared_one():
    """`name` (default, ...) or `a`, `b` (default a, default b), anywhere in the README and docs/."""
    declared = _declared_parameters()
    quoted = []
    for path in [README, *DOCS]:
        for match in re.finditer(r"`([\w.]+)`(?:, `([\w.]+)`)?\s+\((-?[\d.]+)(?:, (-?[\d.]+))?(?! =)",
                                 _text(path)):
            names, values = [match.group(1), match.group(2)], [match.group(3), match.group(4)]
            for name, value in zip(names, values):
                if name in declared and value is not None:
                    quoted.append((path.name, name, float(value.rstrip("."))))
    assert len(quoted) >= 12, quoted
    wrong = [(doc, name, value, declared[name].default) for doc, name, value in quoted
             if value != pytest.approx(float(declared[name].default))]
    assert wrong == []


def test_the_node_docs_name_every_parameter_and_which_change_at_run_time():
    declared = _declared_parameters()
    node_doc = _text(REPO / "docs" / "node.md")
    paragraph = node_doc.split("\nParameters (", 1)[1].split("\n\n", 1)[0]
    named = set(re.findall(r"`([\w.*]+)`", paragraph))
    covered = {name for name in declared
               if name in named or any(n.endswith(".*") and name.startswith(n[:-1]) for n in named)}
    assert sorted(set(declared) - covered) == [], "parameters docs/node.md does not name"
    mirrors = {n for n in named if n.startswith("calibration.")}
    from accel_calibration.ros.parameters import MIRROR_PREFIX, MIRRORS

    assert mirrors == {MIRROR_PREFIX + m[0] for m in MIRRORS}
    unknown = {n for n in named - mirrors if not n.endswith(".*") and n not in declared and "/" not in n}
    assert sorted(unknown) == [], "docs/node.md names parameters the node does not have"
    gates = paragraph.split("the gates (", 1)[1].split("; the only\nones changeable at run time", 1)[0]
    dynamic = {name for name, p in declared.items() if getattr(p, "dynamic", False)}
    assert set(re.findall(r"`([\w.]+)`", gates)) | {"auto_calibrate"} == dynamic


def test_the_node_docs_interface_table_is_the_readmes():
    """docs/node.md repeats the README's table with more words: the same names and types."""
    readme = sorted((kind, tuple(names), type_) for kind, names, type_ in _readme_interface_table())
    rows = _interface_table(_text(REPO / "docs" / "node.md").split("## Running it", 1)[1].split("\n## ", 1)[0])
    flat = sorted((kind, name, type_) for kind, names, type_ in rows for name in names)
    assert flat == sorted((kind, name, type_) for kind, names, type_ in readme for name in names)


# The constants the docs quote: (doc, module, name, value, the doc's words).
DOC_CONSTANTS = [
    ("architecture.md", "accel_calibration.live.worker_protocol", "FEED_PERIOD_S", 0.2,
     "every `FEED_PERIOD_S` (0.2 s)"),
    ("architecture.md", "accel_calibration.live.sample_ring", "RING_RECORDS", 2**18, "(`RING_RECORDS`, 2^18 samples,"),
    ("architecture.md", "accel_calibration.core.session", "RecordingFeed.PART_ROWS", 16_384,
     "parts of PART_ROWS = 16,384"),
    ("architecture.md", "accel_calibration.core.session", "RecordingFeed.LIVE_TEMPERATURE_WAIT_NS", 10**9,
     "`LIVE_TEMPERATURE_WAIT_NS` (1 s)"),
    ("architecture.md", "accel_calibration.core.correction", "TEMPERATURE_DECIMALS", 3, "(`TEMPERATURE_DECIMALS` = 3)"),
    ("architecture.md", "accel_calibration.core.correction", "TEMPERATURE_STEP_DEGC", 0.05,
     "`TEMPERATURE_STEP_DEGC` (0.05 degC)"),
    ("replay.md", "accel_calibration.bag.recording", "STREAM_GROUP_MESSAGES", 16_384, "sqlite3 a fetch of 16,384 rows"),
    ("replay.md", "accel_calibration.core.session", "RecordingFeed.PART_ROWS", 16_384, "in parts of 16,384 samples"),
    ("replay.md", "accel_calibration.bag.corrected_bag", "COPY_GROUP_MESSAGES", 16_384, "written 16,384 IMU messages"),
    ("replay.md", "accel_calibration.bag.corrected_bag", "COPY_GROUP_BYTES", 64 << 20, "(or 64 MB of any topic)"),
    ("node.md", "accel_calibration.ros.node", "SERVICE_QOS.depth", 100, "(service queues hold 100)"),
    ("node.md", "accel_calibration.ros.node", "ARMED_QOS.depth", 10, "std_msgs/Bool (reliable, depth 10)"),
    ("node.md", "accel_calibration.core.stream.screening", "STAMP_JUMP_WINDOWS", 4, "more than 4 windows (2 s) back"),
    ("node.md", "accel_calibration.core.stream.screening", "Counters.INFORMATIONAL",
     frozenset({"samples", "samples_paused", "merge_disagreements"}),
     "except `samples`, `samples_paused` and `merge_disagreements`"),
    ("node.md", "accel_calibration.core.plausibility", "MAX_GYRO_BIAS_RADPS", 1.0, "gyro bias beyond 1 rad/s"),
    ("node.md", "accel_calibration.core.plausibility", "PLAUSIBLE_TEMPERATURE_DEGC", (-100.0, 200.0),
     "a range beyond a sensor's (-100..200 degC)"),
    ("gyro.md", "accel_calibration.core.gyro_gates", "GyroGates.min_motions", 8, "`motions` (min 8)"),
    ("gyro.md", "accel_calibration.core.gyro_gates", "GyroGates.max_residual_rms_mrad", 10.0,
     "`residual` (rms <= 10 mrad)"),
    ("gyro.md", "accel_calibration.core.gyro_gates", "GyroGates.max_scale_sigma_ppm", 1000.0, "(scale <= 1000 ppm,"),
    ("gyro.md", "accel_calibration.core.gyro_gates", "GyroGates.max_misalignment_sigma_mrad", 1.5,
     "misalignment <= 1.5 mrad,"),
    ("gyro.md", "accel_calibration.core.gyro_gates", "GyroGates.scale_band", (0.9, 1.1),
     "`scale` (row gains 0.9..1.1)"),
    ("gyro.md", "accel_calibration.core.gyro_fit", "GyroFitOptions.max_motion_s", 30.0, "(default 30 s)"),
    ("gyro.md", "accel_calibration.core.gyro_fit", "GyroFitOptions.gap_factor", 5.0,
     "an interval over 5x the motion's"),
    ("gyro.md", "accel_calibration.core.plausibility", "GYRO_SCALE_BAND", (0.9, 1.1),
     "gains within `gyro.scale_min`..`gyro.scale_max`, 0.9..1.1 by default"),
    ("noise.md", "accel_calibration.cli.noise", "MIN_STILL_S", 20.0, "a still stretch under 20 s"),
    ("noise.md", "accel_calibration.core.allan", "MIN_CLUSTERS", 9, "(up to N/9 samples per cluster)"),
    ("exports.md", "accel_calibration.core.axis_calibration", "FIT_DIRECTIONS", 600, "over 600 orientations x 21"),
    ("exports.md", "accel_calibration.core.axis_calibration", "TEMPERATURE_STEPS", 21, "x 21 temperatures"),
    ("exports.md", "accel_calibration.core.axis_calibration", "EVALUATION_DIRECTIONS", 2000, "over 2000 orientations"),
    ("exports.md", "accel_calibration.io.autopilot_params", "ARDUPILOT_OFFSET_RANGE_MPS2", (-3.5, 3.5),
     "offsets -3.5..3.5 m/s^2"),
    ("exports.md", "accel_calibration.io.autopilot_params", "ARDUPILOT_SCALE_RANGE", (0.8, 1.2), "scales 0.8..1.2"),
    ("exports.md", "accel_calibration.io.autopilot_params", "ARDUPILOT_TEMPERATURE_RANGE_DEGC", (-70.0, 80.0),
     "TMIN/TMAX -70..80"),
]


@pytest.mark.parametrize("doc, module, name, value, words", DOC_CONSTANTS,
                         ids=[f"{c[0]} {c[2]}" for c in DOC_CONSTANTS])
def test_the_constants_the_docs_quote_are_the_codes(doc, module, name, value, words):
    assert words in re.sub(r"\s+", " ", _text(REPO / "docs" / doc))
    target = importlib.import_module(module)
    for part in name.split("."):
        target = getattr(target, part)
    assert target == value


def test_the_equality_tests_the_docs_list_are_the_makefiles():
    makefile = _text(REPO / "Makefile")
    listed = re.search(r"EQUALITY_TESTS :=((?:.*\\\n)*.*)", makefile).group(1)
    in_makefile = {Path(p).name for p in re.findall(r"test/[\w/]+\.py", listed)}
    section = _text(REPO / "docs" / "architecture.md").split("`EQUALITY_TESTS`", 1)[1].split(")", 1)[0]
    assert {Path(p).name for p in re.findall(r"test/[\w/]+\.py", section)} == in_makefile


def test_the_python_examples_of_models_md_run_and_calibrate(tmp_path, monkeypatch):
    """The two ```python blocks of docs/models.md, run as written on a simulated MPU-6050-like sensor:
    the fit and the session both recover it (a fresh orientation corrected within 2 mg)."""
    from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

    blocks = re.findall(r"```python\n(.*?)```", _text(REPO / "docs" / "models.md"), re.S)
    assert len(blocks) == 2
    rng = np.random.default_rng(20)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    samples = SyntheticImu(errors, spread_orientations(16, rng), dwell_s=2.0, move_s=0.8, rate_hz=200.0, seed=20,
                           temperature_degc=lambda t: 25.0 + 0.0 * t).samples()
    directions = rng.normal(size=(14, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    truth = np.array([[0.3, -0.2, 9.7], [9.8, 0.1, 0.4]])
    namespace = {"pose_means_mps2": errors.raw_from_true(9.80665 * directions), "raw_mps2": errors.raw_from_true(truth),
                 "t_ns": samples.t_ns, "accel_mps2": samples.accel_raw, "gyro_radps": samples.gyro_raw,
                 "temp_stamps_ns": samples.t_ns[::100], "temp_degc": samples.temperature_degc[::100]}
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[0], "models.md: python 1", "exec"), namespace)
    assert namespace["result"].success and (tmp_path / "cal.yaml").exists()
    assert np.abs(namespace["corrected"] - truth).max() < 2e-3 * 9.80665
    exec(compile(blocks[1], "models.md: python 2", "exec"), namespace)
    verdict = namespace["verdict"]
    assert verdict.success, verdict.message
    assert np.abs(verdict.calibration.apply(errors.raw_from_true(truth)) - truth).max() < 2e-3 * 9.80665


def test_an_identity_calibration_is_327_mg_from_the_ardupilot_logs_first_imu(tmp_path, capsys, shared):
    """docs/exports.md: `compare` of an identity calibration against test.BIN's own (was written 335 mg)."""
    from accel_calibration.cli.main import main
    from accel_calibration.core.calibration import Calibration
    from accel_calibration.io.calibration_file import save_calibration

    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    assert main(["compare", str(tmp_path / "cal.yaml"), str(shared("real/ardupilot/test.BIN"))]) == 0
    worst, rms = re.search(r"worst ([\d.]+) mg \(rms ([\d.]+) mg\)", capsys.readouterr().out).groups()
    assert (float(worst), float(rms)) == pytest.approx((327.6, 237.5), abs=0.05)
    assert "327.6 mg away at worst (rms 237.5 mg" in re.sub(r"\s+", " ", _text(REPO / "docs" / "exports.md"))


def _declare_first_chunk_size(data: bytearray, factor: float) -> None:
    """Rewrite the uncompressed size the first MCAP chunk declares, in its Chunk record (0x06; its CRC set
    to 0: not checked, as the spec allows) and in the summary's Chunk Index (0x08), which readers use."""
    import struct

    offset, first = 8, None  # after the magic; records: opcode u8, length u64, body
    while offset < len(data) - 8:
        opcode, length = data[offset], struct.unpack_from("<Q", data, offset + 1)[0]
        body = offset + 9
        if opcode == 0x06 and first is None:  # start u64, end u64, uncompressed_size u64, crc u32, ...
            first = offset
            (size,) = struct.unpack_from("<Q", data, body + 16)
            struct.pack_into("<QI", data, body + 16, int(size * factor), 0)
        elif opcode == 0x08 and struct.unpack_from("<Q", data, body + 16)[0] == first:
            at = body + 32  # start, end, chunk offset, chunk length; then the message index map (u32 bytes)
            at += 4 + struct.unpack_from("<I", data, at)[0] + 8  # and its length u64
            at += 4 + struct.unpack_from("<I", data, at)[0] + 8  # compression string, compressed size
            (size,) = struct.unpack_from("<Q", data, at)
            struct.pack_into("<Q", data, at, int(size * factor))
            return
        offset = body + length
    raise AssertionError("no chunk index for the first chunk")


@pytest.mark.parametrize("compression, factor", [("zstd", 0.5), ("lz4", 2.0)])
def test_an_mcap_chunk_that_decompresses_to_other_than_its_declared_size_is_one_line(tmp_path, capsys, compression,
                                                                                     factor):
    """docs/failures.md: a chunk that decompresses to other than its declared size is one line naming the
    bag, and nothing is written."""
    from accel_calibration.cli.main import main
    from msg_tools.bag_writer import write_session_bag
    from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

    rng = np.random.default_rng(7)
    samples = SyntheticImu(SensorErrors.mpu6050_like(rng), spread_orientations(6, rng), dwell_s=1.0, move_s=0.5,
                           rate_hz=100.0, seed=7).samples()
    bag = tmp_path / "bag"
    write_session_bag(bag, samples, start_ns=1_700_000_000 * 10**9, storage="mcap", chunk_compression=compression)
    (mcap,) = bag.glob("*.mcap")
    data = bytearray(mcap.read_bytes())
    _declare_first_chunk_size(data, factor)
    mcap.write_bytes(bytes(data))
    code = main(["replay", str(bag), "-o", str(tmp_path / "cal.yaml")])
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1 and err.startswith(f"accel-calib: error: {bag}: "), err
    assert "size" in err and not (tmp_path / "cal.yaml").exists(), err
    assert mcap.read_bytes() == bytes(data)


def test_building_the_parser_imports_what_startup_md_says_and_no_more():
    """docs/startup.md: building the parser imports `core.change_rule` (the change rule's defaults), not the
    history (SQLAlchemy's module), the fit,
    scipy.linalg, scipy.stats, matplotlib or rosbags' type store (fresh interpreter)."""
    import subprocess
    import sys

    code = ("import sys\nfrom accel_calibration.cli.main import _parser\n_parser()\n"
            "print(sorted(m for m in ('accel_calibration.core.change_rule', 'accel_calibration.io.history',"
            " 'accel_calibration.core.fit', 'scipy.linalg',"
            " 'scipy.stats', 'matplotlib', 'rosbags.typesys.stores.ros2_jazzy') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "['accel_calibration.core.change_rule']", done.stdout
    assert "building the parser imports `core.change_rule`" in re.sub(r"\s+", " ", _text(REPO / "docs" / "startup.md"))


def test_the_calibration_file_the_readme_shows_is_what_save_calibration_writes(tmp_path):
    """The README's `## Calibration file` block: its keys (and its quality and uncertainty keys) are the
    file's; every other key of a file is one of the optional blocks it names."""
    import yaml

    from accel_calibration.core.fit import fit
    from accel_calibration.io.calibration_file import save_calibration

    section = _text(README).split("## Calibration file", 1)[1].split("\n## ", 1)[0]
    shown = section.split("```yaml", 1)[1].split("```", 1)[0]
    top = set(re.findall(r"^  (\w+):", shown, re.M))
    top |= set(re.findall(r"^  created: \.\.\., (\w+): \.\.\., (\w+):", shown, re.M)[0])
    nested = {key: set(re.findall(r"(\w+): ", re.search(rf"^  {key}: \{{(.*)\}}", shown, re.M).group(1)))
              for key in ("quality", "uncertainty")}
    optional = set(re.findall(r"`(\w+):?`", section.split("Optional blocks:", 1)[1].split("A\nfile from", 1)[0]))
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(14, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    raw = 9.80665 * directions @ np.diag([1.01, 0.99, 1.02]) + [0.1, -0.2, 0.05] + rng.normal(0, 1e-3, (14, 3))
    result = fit(raw)
    assert result.success, result.message
    save_calibration(result.calibration, tmp_path / "cal.yaml")
    written = yaml.safe_load((tmp_path / "cal.yaml").read_text())["accel_calibration"]
    assert top <= set(written), top - set(written)
    assert set(written) <= top | optional, set(written) - top - optional
    for key, keys in nested.items():
        assert keys == set(written[key]), (key, keys, set(written[key]))
    assert {"temperature", "gyro_bias_radps", "gyro_matrix", "gyro_quality", "dividing_head"} <= optional


def test_every_bare_test_name_the_docs_give_exists():
    """`test_core_imports_no_ros` without its file: some test file under test/ defines it."""
    defined = set()
    for path in (REPO / "test").rglob("*.py"):
        defined |= {node.name for node in ast.walk(ast.parse(_text(path)))
                    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))}
    named = {(path.name, name) for path in [README, *DOCS]
             for name in re.findall(r"`(test_\w+)`", _text(path))}
    assert named, "the docs name no test"
    assert sorted((doc, name) for doc, name in named if name not in defined) == []
