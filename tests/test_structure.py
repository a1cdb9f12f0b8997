"""The package's shape: imports run one way with no cycles, and commands answer before importing torch.

Imports run commands -> loop -> strategies -> collectors/evaluation -> suites/dataset -> leaf modules; an import
against that direction (or any cycle, including one held together by an import inside a function) fails here.
"""

from __future__ import annotations

import ast
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "adademo_lerobot"
QUICKSTART = f"--config_path={PACKAGE.parent / 'recipes' / 'quickstart.yaml'}"

# Lower layers never import higher ones. A module's layer is that of the longest matching prefix.
LAYERS = [
    # leaves: shared types and helpers
    ("adademo_lerobot.core", 0),
    ("adademo_lerobot.dataset.layout", 0),
    ("adademo_lerobot", 0),  # the package __init__ (the version check; it changes nothing of the process)
    # simulators and data
    ("adademo_lerobot.suites", 1),
    ("adademo_lerobot.dataset", 1),
    ("adademo_lerobot.samplers", 1),
    # experts and evaluation
    ("adademo_lerobot.collectors", 2),
    ("adademo_lerobot.evaluation", 2),
    ("adademo_lerobot.executors", 2),
    # strategies (Algorithm 1)
    ("adademo_lerobot.strategies", 3),
    # what each command does, the plugins LeRobot loads, and the outer loop above them
    ("adademo_lerobot.loop", 4),
    ("adademo_lerobot.lerobot_plugins", 4),
    ("adademo_lerobot.loop.run", 5),
    # entry points
    ("adademo_lerobot.commands", 6),
]


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(module: str) -> int:
    matches = [
        (len(prefix), n) for prefix, n in LAYERS if module == prefix or module.startswith(prefix + ".")
    ]
    assert matches, f"{module} has no layer in tests/test_structure.py"
    return max(matches)[1]


def runtime_imports(tree: ast.AST) -> list[str]:
    """Every adademo_lerobot import, at module level or inside functions, except under `if TYPE_CHECKING:`."""
    found = []

    def visit(node):
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            return
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("adademo_lerobot"):
            found.append(node.module)
            found.extend(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.extend(a.name for a in node.names if a.name.startswith("adademo_lerobot"))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


def import_graph() -> dict[str, set[str]]:
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {m: set() for m in modules}
    for m, path in modules.items():
        for target in runtime_imports(ast.parse(path.read_text())):
            parts = target.split(".")
            # importing a.b.c runs the package a.b (its __init__) first
            for i in range(1, len(parts) + 1):
                t = ".".join(parts[:i])
                if t in modules and t != m and not m.startswith(t + "."):
                    graph[m].add(t)
    return graph


def test_imports_have_no_cycles():
    graph, state, stack, cycles = import_graph(), {}, [], []

    def dfs(u):
        state[u] = "open"
        stack.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == "open":
                cycles.append(" -> ".join([*stack[stack.index(v) :], v]))
            elif v not in state:
                dfs(v)
        stack.pop()
        state[u] = "done"

    for m in sorted(graph):
        if m not in state:
            dfs(m)
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_no_module_over_400_lines_without_a_reason_at_its_top():
    long = [
        f"{path.relative_to(PACKAGE.parent)} ({n} lines)"
        for path in sorted(PACKAGE.rglob("*.py"))
        if (n := len(path.read_text().splitlines())) > 400
        and "Longer than 400 lines:" not in (ast.get_docstring(ast.parse(path.read_text())) or "")
    ]
    assert not long, "split these along their seams, or say at their top why not:\n" + "\n".join(long)


def test_imports_run_one_way():
    upward = [
        f"{m} (layer {layer(m)}) imports {t} (layer {layer(t)})"
        for m, targets in import_graph().items()
        for t in targets
        if layer(t) > layer(m)
    ]
    assert not upward, "imports against the layering:\n" + "\n".join(sorted(upward))


PROBE = """
import sys
sys.argv = {argv!r}
from adademo_lerobot.commands.{script} import main
try:
    main()
    code = 0
except SystemExit as exit:
    code = exit.code
print("RESULT", code, "torch" in sys.modules, "lerobot" in sys.modules)
"""


@pytest.mark.parametrize(
    ("script", "args", "expected_code"),
    [
        ("collect", ["--help"], 0),
        ("collect", ["--suite.tasks=reach-v3,pusj-v3", "--dataset.root=/nonexistent/ds"], 2),
        ("collect", ["--episodes_per_task=x"], 2),
        ("eval", ["--help"], 0),
        (
            "eval",
            ["--dataset.root=/nonexistent", "--episodes_per_task=0", "--policy.path=p", "--output_dir=o"],
            2,
        ),
        ("expand", ["--help"], 0),
        ("expand", ["--dataset.root=/nonexistent/ds", "--strategy.type=greedy"], 2),
        ("expand", ["--dataset.root=/nonexistent/ds"], 2),
        ("push", ["--help"], 0),
        ("push", ["--dataset.root=/nonexistent/ds", "--repo_id=bad id"], 2),
        ("report", ["--run_dir=/nonexistent/run"], 2),
        # the commands whose configs hold LeRobot's policy / robot / teleoperator configs (registries that
        # import torch) answer these from their first parse
        ("run", ["--help"], 0),
        ("run", [QUICKSTART, "--run_dir=/tmp/r", "--rounds=x"], 2),
        ("run", [QUICKSTART, "--run_dir=/tmp/r", "--strategy.type=greedy"], 2),
        (
            "run",
            [
                "--run_dir=/tmp/r",
                "--train.policy.type=act",
                "--strategy.budget=[5]",
                "--strategy.target_successes=[3]",
            ],
            2,
        ),
        ("run", ["--run_dir=/tmp/r"], 2),  # no policy to train
        ("train", ["--help"], 0),
        ("train", ["--policy.type=act", "--dataset.root=/d", "--sampler=greedy"], 2),
        ("train", ["--policy.type=act", "--sampler_alpha=-1"], 2),
        ("train", ["--policy.type=act", "--lr_schedule=linear"], 2),
        ("run", ["--run_dir=/tmp/r", "--train.policy.type=act", "--train.lr_schedule=linear"], 2),
        ("run", ["--run_dir=/tmp/r", "--train.policy.type=act", "--train.mode=resume"], 2),
        ("record", ["--help"], 0),
        ("record", ["--robot.type=so101_follower", "--robot.port=/dev/x"], 2),  # no teleoperator
        ("record", ["--robot.type=so101_follower", "--teleop.type=so101_leader", "--policy.path=p"], 2),
        (
            "record",
            ["--robot.type=x", "--teleop.type=y", "--policy.path=p", "--dataset.root=/d", "--judge=z"],
            2,
        ),
        ("record", ["--robot.type=x", "--teleop.type=y", "--policy.path=p", "--target_successes=5"], 2),
        ("record", ["--robot.type=x", "--teleop.type=y", "--policy.path=p", "--strategy.type=uniform"], 2),
    ],
)
def test_commands_answer_bad_input_and_help_without_importing_torch(script, args, expected_code):
    """`--help`, flag errors and dataset checks answer before torch and LeRobot are imported (the seconds-long
    part of a command's start): the import cost is measured as what is imported, not as a wall time."""
    code = PROBE.format(argv=[f"adademo-{script}", *args], script=script)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    result = [line for line in proc.stdout.splitlines() if line.startswith("RESULT")]
    assert result, proc.stderr[-2000:]
    _, exit_code, torch_loaded, lerobot_loaded = result[-1].split()
    assert int(exit_code) == expected_code, proc.stderr[-2000:]
    assert (torch_loaded, lerobot_loaded) == ("False", "False")
    if expected_code == 2:
        assert proc.stderr.strip().splitlines()[-1].startswith("error: ")


def test_importing_the_library_changes_nothing_of_the_process():
    """Importing adademo_lerobot and its library modules sets no environment variable and no matplotlib backend
    (the commands and LeRobot's import of our plugins pick the GL backend; reports draw without pyplot)."""
    modules = sorted(
        module_name(p)
        for p in PACKAGE.rglob("*.py")
        if not module_name(p).startswith(("adademo_lerobot.commands", "adademo_lerobot.lerobot_plugins"))
    )
    code = (
        "import importlib, os, sys\n"
        # What the libraries we build on set when imported is theirs (gymnasium-robotics: pygame's and SDL's;
        # accelerate: torch inductor's cache).
        "import accelerate, gymnasium_robotics, lerobot.policies, lerobot.datasets.lerobot_dataset, metaworld\n"
        "before = dict(os.environ)\n"
        f"for m in {modules!r}: importlib.import_module(m)\n"
        "changed = sorted(k for k in set(before) | set(os.environ) if before.get(k) != os.environ.get(k))\n"
        "print('CHANGED', changed, 'PYPLOT', 'matplotlib.pyplot' in sys.modules)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert "CHANGED [] PYPLOT False" in proc.stdout, proc.stdout + proc.stderr[-2000:]


def test_the_example_plugins_import_only_the_documented_plugin_interface():
    """docs/extending.md, "What a plugin imports", lists the modules a plugin may build on; the example plugins
    (third-party code as a user writes it) import nothing else of the package."""
    doc = (PACKAGE.parent / "docs" / "extending.md").read_text()
    section = doc.split("## What a plugin imports", 1)[1].split("\n## ", 1)[0]
    interface = set(re.findall(r"^\| `(adademo_lerobot\.[\w.]+)` \|", section, flags=re.MULTILINE))
    assert len(interface) >= 8, interface
    for module in interface:
        assert importlib.util.find_spec(module) is not None, module
    used = {}
    for path in sorted((PACKAGE.parent / "examples").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                if name == "adademo_lerobot" or name.startswith("adademo_lerobot."):
                    used.setdefault(name, []).append(path.relative_to(PACKAGE.parent))
    assert used, "the examples import the package"
    assert set(used) <= interface, {m: p for m, p in used.items() if m not in interface}
