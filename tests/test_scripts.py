"""The helper scripts: scripts/*.py use only masknet's public API and still run, and
scripts/train_shipped.sh resumes from the checkpoint that training writes."""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from masknet.training.loop import CHECKPOINT

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "scripts").glob("*.py"))

# Internal modules that hold no public API, beside every module or name with a leading _.
INTERNAL = ("masknet.registration.stages.rounds", "masknet.registration.solvers.backends")


def _private(module: str, names: list[str]) -> list[str]:
    """What an import of ``names`` from ``module`` (a masknet module) reaches that is
    private: a module path part or a name with a leading underscore, or an internal
    module (or anything under it)."""
    found = []
    if any(part.startswith("_") for part in module.split(".")):
        found.append(module)
    elif any(module == m or module.startswith(m + ".") for m in INTERNAL):
        found.append(module)
    found += [f"{module}.{name}" for name in names if name.startswith("_")]
    return found


def private_imports(source: str) -> list[str]:
    """Every private masknet module or name that ``source`` imports."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "masknet":
                    found += _private(alias.name, [])
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module.split(".")[0] == "masknet":
                names = [alias.name for alias in node.names]
                # `from masknet.cli import _common` names a private module too
                found += _private(node.module, names)
    return found


def test_the_check_finds_private_imports():
    source = """
import masknet._atomic
from masknet._atomic import atomic_target
from masknet.cli import _common
from masknet.cli._common import write_views
from masknet.registration.stages.rounds import keep_source_points
from masknet.registration.solvers.backends import BACKENDS
from masknet.registration.solvers.backends.base import adapter
from masknet.io import _read_trimesh
from masknet.io import read_points
from masknet import register
import numpy._core
"""
    assert private_imports(source) == [
        "masknet._atomic",
        "masknet._atomic",
        "masknet.cli._common",
        "masknet.cli._common",
        "masknet.registration.stages.rounds",
        "masknet.registration.solvers.backends",
        "masknet.registration.solvers.backends.base",
        "masknet.io._read_trimesh",
    ]


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_scripts_use_only_the_public_api(script):
    assert private_imports(script.read_text()) == []


_HELP = """
import contextlib, io, json, runpy, sys
codes = {}
for script in sys.argv[1:]:
    sys.argv = [script, "--help"]
    with contextlib.redirect_stdout(io.StringIO()):
        try:
            runpy.run_path(script, run_name="__main__")
            codes[script] = "no exit"
        except SystemExit as exc:
            codes[script] = exc.code
print(json.dumps(codes))
"""


def test_every_script_imports_and_answers_help():
    """Their imports resolve (one process for all: the imports are shared)."""
    run = subprocess.run(
        [sys.executable, "-c", _HELP, *map(str, SCRIPTS)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    codes = json.loads(run.stdout.strip().splitlines()[-1])
    assert codes == {str(s): 0 for s in SCRIPTS}


def checkpoint_files(script: str) -> set[str]:
    """The checkpoint files a shell script names (``checkpoint.<ext>``)."""
    return set(re.findall(r"\bcheckpoint\.\w+", script))


def resume_check(script: str) -> str:
    """The line of ``scripts/train_shipped.sh`` that decides whether to pass --resume."""
    return next(line for line in script.splitlines() if line.startswith("resume()"))


def test_the_resume_check_is_read_as_intended():
    old = 'resume() { [ -f "$1/checkpoint.pt" ] && echo --resume; }\n$M train $(resume runs/a)\n'
    assert checkpoint_files(old) == {"checkpoint.pt"}
    assert resume_check(old).startswith("resume() {")


def test_train_shipped_resumes_from_the_checkpoint_training_writes():
    """train_shipped.sh must look for the file the training loop writes every epoch, or
    a killed step restarts from scratch instead of resuming."""
    training = ROOT / "src" / "masknet" / "training"
    loop = ast.parse((training / "loop.py").read_text())
    savers = [
        node
        for node in ast.walk(loop)
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Saver"
    ]
    assert [ast.unparse(call.args[0]) for call in savers] == ["out / CHECKPOINT"]
    # The saver writes to that path and nowhere else.
    epoch = ast.parse((training / "epoch.py").read_text())
    saves = [
        node
        for node in ast.walk(epoch)
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "save_checkpoint"
    ]
    assert [ast.unparse(call.args[0]) for call in saves] == ["self.path"]
    script = (ROOT / "scripts" / "train_shipped.sh").read_text()
    assert f'[ -f "$1/{CHECKPOINT}" ]' in resume_check(script)
    assert checkpoint_files(script) == {CHECKPOINT}
    assert "$(resume runs/" in script


def test_every_script_runs_its_main_through_run_script():
    # A MaskNetError from a script's main is then one line and exit code 2, as in the CLI.
    for script in SCRIPTS:
        assert script.read_text().rstrip().endswith("run_script(main)"), script.name


def test_a_script_given_a_missing_folder_says_so_in_one_line(tmp_path):
    done = subprocess.run(
        [
            sys.executable,
            str(ROOT / "scripts" / "rounds_on_real_pair.py"),
            "--scans",
            str(tmp_path / "nowhere"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1 and lines[0].startswith("rounds_on_real_pair.py: error: "), lines
    assert "nowhere" in lines[0]


def test_the_relay_command_is_one_the_cli_takes():
    """scripts/relay.sh resumes the run with a `masknet train` line the parser accepts, into
    the folder the script names, with mid-epoch checkpoints and --resume."""
    import shlex

    from masknet.cli import build_parser

    script = (ROOT / "scripts" / "relay.sh").read_text()
    start = script.index('"$MASKNET" train')
    line = script[start : script.index(">>", start)].replace("\\\n", " ")
    words = shlex.split(line.replace('"$MASKNET"', "masknet").replace('"$DATA"', "data.npz"))
    run = re.search(r"^RUN=(\S+)$", script, flags=re.M).group(1)
    words = [run if word == "$RUN" else word for word in words[1:]]
    args = build_parser().parse_args(words)
    assert args.model == "crossmasknet" and args.resume and args.checkpoint_minutes
    assert args.output == run == "relay/crossmasknet_fpfh_seen20" and args.categories == "seen"
    assert args.model_config == {"descriptors": "fpfh"}
    assert (ROOT / run / "README.md").exists()
