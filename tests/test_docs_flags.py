"""The docs cannot drift from the flags: every `--flag` that README.md and docs/ name is a flag of a command, and
every default they give is the config dataclass's.

The commands and their configs are read where the commands get them: pyproject.toml's console scripts, each
calling `run_command(target, Config[, "module:FullConfig"])` (`adademo_lerobot/loop/cli.py`). A flag is a dotted path
through that config's dataclass fields, through every registered type of a choice (`--suite.*`, `--collector.*`,
`--strategy.*`; under a heading that names one type in backquotes, as expand.md's per strategy, only that
type's fields) and through LeRobot's policy configs; a LeRobot env config given flag by flag (`--suite.env.*`) is
LeRobot's to check.

Where a flag is named decides whose it is: on a line or in a code span that runs a command (`adademo-run ...`),
that command's; otherwise the page's (docs/commands/X.md: `adademo-X`); otherwise, or when that command does not
have it, any command's. Another program's flags (`lerobot-eval ...`, `ray start --head`, sections headed by a
`lerobot-*` command) are not ours to check.

A default is read from a flags table (columns `flag` and `default`) or from prose right after the flag:
`--flag` (default X), `--flag=X` (default), `--flag` default X. It must equal the dataclass default; where the
dataclass leaves a field unset (None, or no per-round value) the docs may describe the default in words
(`2 x (E + CAP)`, `start a local Ray`, `-`, `required`), and a value they give must be the one the field's own
comment states (`# ... (default 10)`). Reads text and config classes: no simulation.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import re
import sys
import tomllib
import types
import typing
from functools import cache
from pathlib import Path

import draccus
import pytest

from adademo_lerobot.core.plugins import import_plugins
from adademo_lerobot.loop.configs import LEROBOT_CHOICE

# The commands import the installed plugins before reading flags; extending.md names the example plugin's flags.
import_plugins(sys.path)

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])

# Left out of the check: command -> the pages about it (its pages and every line or span that runs it are skipped,
# and its config is not read). Empty: every command is checked.
SKIPPED_COMMANDS: dict[str, tuple[str, ...]] = {}
# Flags the docs name as gone, so that a user of an earlier release finds what replaced them (docs/commands/
# expand.md: the strategy's settings before 0.3; run.md: `--train.torch_threads`). `test_removed_flags_are_gone`
# checks that no command has them.
REMOVED_FLAGS = {
    "target_successes": "now --strategy.target_successes",
    "budget": "now --strategy.budget",
    "max_demos_per_task": "now --strategy.max_demos_per_task",
    "max_eval_episodes_per_task": "now --strategy.max_eval_episodes_per_task (adademo-record, before 0.4)",
    "demos_per_task": "now --strategy.demos_per_task",
    "posterior_decay": "now --strategy.posterior_decay",
    "train.torch_threads": "now --torch_threads",
}
# Every command takes these (`adademo_lerobot/loop/cli.py`: draccus' help, and recipes and presets).
UNIVERSAL_FLAGS = {"help", "config_path"}
# extending.md's stand-in for any registry of types (`--x.type=mine`, `--x.FIELD`).
PLACEHOLDERS = {"x"}
# No value: how the docs say that a flag has no default.
NO_VALUE = {"-", "none", "required", "null"}

FLAG = re.compile(r"(?<![\w-])--([a-z][a-z0-9_]*(?:\.(?:[a-z0-9_]+|\*))*)(\.)?(?![\w-])(?:=(\S+))?")
SPAN = re.compile(r"`([^`]+)`")
FENCE = re.compile(r"^\s*(```|~~~)")
COMMAND = re.compile(r"^(?:adademo-([a-z]+)|\S*adademo_lerobot\.commands\.([a-z]+))$")
FOREIGN_SECTION = re.compile(r"\blerobot-(?:eval|train|record)\b")
# Prose defaults right after a flag's code span.
DEFAULT_GIVEN = re.compile(r"^\s*\(default:?\s+(`[^`]+`|[^);,`]+)")
DEFAULT_IS_VALUE = re.compile(r"^\s*(?:\(default[);]|,\s*the default\b)")
DEFAULTS_BEFORE = re.compile(r"\bdefaults?(?: changed)?:?\s*$")  # `--steps=3000 --batch_size=64` after it
DEFAULT_IN_CELL = re.compile(r"[(;]\s*default (`[^`]+`|[\w.+-]+)\)")  # a flags table without a default column
DEFAULT_WORD = re.compile(r"^\s*,?\s*default\s+(`[^`]+`|[^\s);,]+)")
RECIPE_SETTING = re.compile(
    r"^([a-z_]+(?:\.[a-z_]+)+)=([\w.+-]+)$"
)  # a flag without its dashes, as in a recipe


def flag_path(m: re.Match) -> str:
    """`--ray.*`, `--strategy.` -> `ray`, `strategy` (the flags below a field)."""
    return m.group(1).removesuffix(".*")


def page_id(path: Path) -> str:
    return str(path.relative_to(ROOT))


# -- the commands' configs ---------------------------------------------------------------------------------------
@cache
def command_configs() -> dict[str, type]:
    """Console script -> the config class its `run_command` parses (the full one where there are two)."""
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    configs = {}
    for command, target in scripts.items():
        if command in SKIPPED_COMMANDS:
            continue
        module_name = target.split(":")[0]
        tree = ast.parse((ROOT / f"{module_name.replace('.', '/')}.py").read_text())
        call = next(
            n
            for n in ast.walk(tree)
            if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "run_command"
        )
        config = getattr(importlib.import_module(module_name), call.args[1].id)
        if len(call.args) > 2:  # LeRobot's config, of which `config` holds our own flags
            module, name = call.args[2].value.split(":")
            config = getattr(importlib.import_module(module), name)
        configs[command] = config
    return configs


@dataclasses.dataclass(frozen=True)
class Field:
    owner: type
    name: str
    default: typing.Any


ANY = "checked by LeRobot"  # a LeRobot config the command hands to LeRobot: its flags are LeRobot's


def default_of(f: dataclasses.Field) -> typing.Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def non_optional(tp):
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def registry(tp) -> type | None:
    return tp if isinstance(tp, type) and issubclass(tp, draccus.ChoiceRegistry) else None


def resolve(cls: type, parts: list[str], scope: frozenset[str]) -> list[Field] | str:
    """The fields the dotted flag `parts` names in `cls` (several through a choice's types), or ANY."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    name, rest = parts[0], parts[1:]
    if name not in fields:
        return []
    f = fields[name]
    tp = non_optional(typing.get_type_hints(cls)[name])
    if f.metadata.get(LEROBOT_CHOICE) == "policy":
        from adademo_lerobot.loop.cli import lerobot_choice_type

        tp = lerobot_choice_type("policy")
    elif LEROBOT_CHOICE in f.metadata:
        return ANY
    if not rest or rest == ["*"]:
        return [Field(cls, name, default_of(f))]
    if tp is dict or typing.get_origin(tp) is dict:
        return ANY
    choice = registry(tp)
    if choice is not None:
        if rest == ["path"] and name in getattr(cls, "__get_path_fields__", list)():
            return ANY  # LeRobot's `--policy.path`
        known = choice.get_known_choices()
        if rest == ["type"]:
            instance = default_of(f)
            default = (
                None if instance in (None, dataclasses.MISSING) else choice.get_choice_name(type(instance))
            )
            return [Field(cls, f"{name}.type", default)]
        scoped = {n: c for n, c in known.items() if n in scope} or known
        found: list[Field] = []
        for sub in scoped.values():
            more = resolve(sub, rest, scope)
            if more == ANY:
                return ANY
            found += more
        return found
    if dataclasses.is_dataclass(tp):
        return resolve(tp, rest, scope)
    return []


def stated_default(field: Field) -> str | None:
    """The default a field left unset states in its own comment: `# ... (default 10)`."""
    for cls in field.owner.__mro__:
        try:
            lines = inspect.getsource(cls).splitlines()
        except (OSError, TypeError):
            continue
        for i, line in enumerate(lines):
            if re.match(rf"\s+{re.escape(field.name)}\s*:", line):
                comment = []
                for above in reversed(lines[:i]):
                    if not above.strip().startswith("#"):
                        break
                    comment.insert(0, above.strip().lstrip("#").strip())
                found = re.search(r"\(default ([^)]+)\)", " ".join(comment))
                return found and found.group(1)
    return None


def same(doc: str, value) -> bool:
    if isinstance(value, bool):
        return doc.lower() == str(value).lower()
    if isinstance(value, int | float):
        try:
            return float(doc) == float(value)
        except ValueError:
            return False
    return doc == str(value)


def literal(doc: str) -> bool:
    return re.fullmatch(r"[\w.+-]+", doc) is not None and doc.lower() not in NO_VALUE


def agrees(doc: str, field: Field) -> bool:
    value = field.default
    if isinstance(value, tuple) and len(value) == 1:  # one per-round value
        value = value[0]
    if value is None or value is dataclasses.MISSING or (isinstance(value, tuple | dict) and not value):
        if not literal(doc):  # "-", "required", or the default in words
            return True
        stated = stated_default(field)
        return stated is not None and same(doc, stated)
    return literal(doc) and same(doc, value)


# -- what the docs say -------------------------------------------------------------------------------------------
@dataclasses.dataclass
class Mention:
    page: str
    line: int
    flag: str  # the dotted path, without a trailing `.` or `.*`
    default: str | None
    command: str | None  # adademo-X whose flag it is, or None: the page's, or any command's
    scope: frozenset[str]


def clean(value: str) -> str:
    return value.strip().strip("`").strip().rstrip(".,;:").strip("'\"")


def split_row(line: str) -> list[str]:
    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]


def span_command(span: str) -> tuple[str | None, bool, int]:
    """(the adademo command a span or code line runs, whether it runs another program, where its flags start)."""
    tokens = list(re.finditer(r"\S+", span))
    if not FLAG.search(span) or tokens[0].group().lstrip("[(").startswith("--"):
        return None, False, 0
    for token in tokens:
        m = COMMAND.match(token.group())
        if m:
            return f"adademo-{m.group(1) or m.group(2)}", False, token.end()
    return None, True, 0


def page_mentions(page: Path) -> list[Mention]:
    name = page_id(page)
    page_command = next((c for c, pages in SKIPPED_COMMANDS.items() if name in pages), None)
    if name.startswith("docs/commands/"):
        page_command = f"adademo-{page.stem}"
    found: list[Mention] = []
    headings: list[tuple[int, str]] = []
    lines = page.read_text().splitlines()
    in_code, code_command, code_foreign, continued = False, None, False, False
    paragraph: list[tuple[int, str]] = []
    table: dict[str, int] | None = None
    section_command = page_command  # the command a section's prose last named runs on for the section

    def scope() -> frozenset[str]:
        return frozenset(w for _, text in headings for w in SPAN.findall(text))

    def foreign_section() -> bool:
        return any(FOREIGN_SECTION.search(text) for _, text in headings)

    def flush() -> None:
        nonlocal section_command
        if paragraph:
            more, section_command = prose_mentions(
                name, paragraph, section_command, scope(), foreign_section()
            )
            found.extend(more)
            paragraph.clear()

    for number, line in enumerate(lines, 1):
        if FENCE.match(line):
            flush()
            in_code, continued = not in_code, False
            continue
        if in_code:
            if not continued:
                code_command, code_foreign, start = span_command(line.split(" #")[0])
            else:
                start = 0
            continued = line.rstrip().endswith("\\")
            if code_foreign:
                continue
            for m in FLAG.finditer(line.split(" #")[0], start):
                found.append(Mention(name, number, flag_path(m), None, code_command or page_command, scope()))
            continue
        heading = re.match(r"^(#+)\s+(.*)", line)
        if heading:
            flush()
            level = len(heading.group(1))
            section_command = page_command
            headings = [h for h in headings if h[0] < level] + [(level, heading.group(2))]
            continue
        if line.strip().startswith("|"):
            cells = split_row(line)
            if table is None and number < len(lines) and re.match(r"^\s*\|\s*-{3}", lines[number]):
                header = [c.lower() for c in cells]
                table = (
                    {c: header.index(c) for c in ("flag", "default") if c in header}
                    if "flag" in header
                    else {}
                )
                continue
            if table and len(cells) > max(table.values()) and not re.match(r"^-{3}", cells[0]):
                flag = FLAG.search(cells[table["flag"]])
                if flag:
                    if "default" in table:
                        default = clean(cells[table["default"]])
                    else:
                        given = DEFAULT_IN_CELL.search(" ".join(cells))
                        default = given and clean(given.group(1))
                    found.append(Mention(name, number, flag_path(flag), default, page_command, scope()))
                    continue
        else:
            table = None
        if not line.strip():
            flush()
        else:
            paragraph.append((number, line))
    flush()
    return found


def prose_mentions(
    page: str, paragraph: list[tuple[int, str]], command: str | None, scope: frozenset[str], foreign: bool
) -> tuple[list[Mention], str | None]:
    """The flags of a paragraph, and the command it names last (the section's from then on)."""
    text = "\n".join(line for _, line in paragraph)
    first = paragraph[0][0]
    found: list[Mention] = []
    last: tuple[Mention, str | None] | None = None
    for span in SPAN.finditer(text):
        line = first + text.count("\n", 0, span.start())
        after = text[span.end() : span.end() + 120].replace("\n", " ")
        content = span.group(1).replace("\\|", "|")
        named, other_program, start = span_command(content)
        if other_program:
            continue
        if named:
            command = named  # the paragraph goes on about this command
        elif foreign:
            continue
        flags = list(FLAG.finditer(content, start))
        if not flags:
            setting = RECIPE_SETTING.match(content)
            if setting and DEFAULT_IS_VALUE.match(after):  # `train.mode=scratch` (default): --train.mode's
                found.append(Mention(page, line, setting.group(1), setting.group(2), command, scope))
            elif last and DEFAULT_IS_VALUE.match(after) and content in (last[1] or "").split("|"):
                last[0].default = content  # `value` (default), after the flag whose values it is one of
            continue
        listed = DEFAULTS_BEFORE.search(text[max(0, span.start() - 40) : span.start()].replace("\n", " "))
        for m in flags:
            default = clean(m.group(3)) if listed and m.group(3) else None
            found.append(Mention(page, line, flag_path(m), default, named or command, scope))
        m, mention = flags[-1], found[-1]
        given = DEFAULT_GIVEN.match(after) or DEFAULT_WORD.match(after)
        if given:
            mention.default = clean(given.group(1))
        elif DEFAULT_IS_VALUE.match(after) and m.group(3) and "|" not in m.group(3):
            mention.default = clean(m.group(3))
        last = (mention, m.group(3))
    return found, command


# -- the checks --------------------------------------------------------------------------------------------------
def problems(page: Path) -> list[str]:
    configs = command_configs()
    out = []
    for mention in page_mentions(page):
        parts = mention.flag.split(".")
        if mention.command in SKIPPED_COMMANDS or parts[0] in PLACEHOLDERS or mention.flag in UNIVERSAL_FLAGS:
            continue
        own = [configs[mention.command]] if mention.command in configs else []
        fields: list[Field] | str = []
        for candidates in (own, list(configs.values())):
            for config in candidates:
                more = resolve(config, parts, mention.scope)
                fields = ANY if more == ANY or fields == ANY else fields + more
            if fields:
                break
        where = f"{mention.page}:{mention.line}: --{mention.flag}"
        if not fields:
            if mention.flag in REMOVED_FLAGS or mention.flag in lerobot_main_flags():
                continue
            whose = mention.command or "any command"
            out.append(f"{where} is a flag of no command (looked in {whose})")
        elif (
            fields != ANY
            and mention.default is not None
            and not any(agrees(mention.default, f) for f in fields)
        ):
            actual = ", ".join(
                dict.fromkeys(
                    f"{f.owner.__name__}.{f.name} = {f.default!r}"
                    + (f" (its comment: default {stated_default(f)})" if stated_default(f) else "")
                    for f in fields
                )
            )
            out.append(f"{where}: the docs say default {mention.default!r}, the config has {actual}")
    return out


@cache
def lerobot_main_flags() -> frozenset[str]:
    """`lerobot-train` flags of LeRobot main only, which adademo-train refuses (train.md names them)."""
    from adademo_lerobot.loop import lerobot_training

    return frozenset(lerobot_training._NEWER_FLAGS)


@pytest.mark.parametrize("page", PAGES, ids=page_id)
def test_every_flag_and_default_the_docs_name_is_the_configs(page):
    skipped = [c for c, pages in SKIPPED_COMMANDS.items() if page_id(page) in pages]
    if skipped:
        pytest.skip(f"{skipped[0]} is left out for now (SKIPPED_COMMANDS)")
    found = problems(page)
    assert not found, "docs and configs disagree:\n" + "\n".join(found)


def test_removed_flags_are_gone():
    configs = command_configs()
    still = [f for f in REMOVED_FLAGS for c in configs.values() if resolve(c, f.split("."), frozenset())]
    assert not still, f"REMOVED_FLAGS names flags a command has: {still}"


def test_the_check_reads_flags_and_defaults():
    """The reader finds the flags tables and prose defaults (an empty reading would pass everything)."""
    expand = page_mentions(ROOT / "docs" / "commands" / "expand.md")
    defaults = {(m.flag, m.default) for m in expand if m.default is not None}
    assert ("strategy.failure_worth", "3") in defaults and ("commit_every", "10") in defaults
    assert ("plan_episodes_per_task", "20") in defaults
    run = {(m.flag, m.default) for m in page_mentions(ROOT / "docs" / "commands" / "run.md")}
    assert ("train.mode", "scratch") in run and ("train.steps_schedule", "proportional") in run
    collect = {(m.flag, m.default) for m in page_mentions(ROOT / "docs" / "commands" / "collect.md")}
    assert ("suite.obs_type", "state") in collect and ("suite.image_size", "128") in collect
    assert ("collector.max_attempts", "3") in collect and ("collector.type", "scripted") in collect
    concepts = {(m.flag, m.default) for m in page_mentions(ROOT / "docs" / "concepts.md")}
    assert ("strategy.max_demos_per_task", "50") in concepts  # a flags table without a default column
    bad = Mention("x.md", 1, "strategy.failure_worth", "4", "adademo-expand", frozenset({"budgeted"}))
    fields = resolve(command_configs()["adademo-expand"], bad.flag.split("."), bad.scope)
    assert [f.default for f in fields] == [3.0] and not agrees("4", fields[0])
    assert not resolve(command_configs()["adademo-expand"], ["no_such_flag"], frozenset())


# `--suite.type=metaworld|fetch|adroit|lerobot_env`: a list of the types a choice takes.
TYPE_LIST = re.compile(r"--(suite|collector|strategy)\.type=([a-z_]+(?:\|[a-z_]+)+)")


def test_a_list_of_types_names_every_type_this_package_registers():
    """Where the docs list the types of `--suite`, `--collector` or `--strategy`, the list is whole: a type added
    to the package and left out of a page's list (run.md once listed no `planner`) fails here. A plugin's own
    types (registered by the example plugins imported above) are the plugin's to document."""
    from adademo_lerobot.collectors.base import CollectorConfig
    from adademo_lerobot.strategies.base import StrategyConfig
    from adademo_lerobot.suites.base import SuiteConfig

    registries = {"suite": SuiteConfig, "collector": CollectorConfig, "strategy": StrategyConfig}
    ours = {
        name: {
            t for t, cls in reg.get_known_choices().items() if cls.__module__.startswith("adademo_lerobot.")
        }
        for name, reg in registries.items()
    }
    lists = [
        (page_id(page), i, m.group(1), set(m.group(2).split("|")))
        for page in PAGES
        for i, line in enumerate(page.read_text().splitlines(), 1)
        for m in TYPE_LIST.finditer(line)
    ]
    assert {choice for _, _, choice, _ in lists} == set(registries)  # each choice is listed somewhere
    wrong = [
        f"{page}:{line}: --{choice}.type lists {'|'.join(sorted(listed))}, the package has "
        f"{'|'.join(sorted(ours[choice]))}"
        for page, line, choice, listed in lists
        if listed != ours[choice]
    ]
    assert not wrong, "\n".join(wrong)
