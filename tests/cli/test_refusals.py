"""Every refusal of the command line, one table per kind.

A refusal (bad options, outputs that cannot be written, options that contradict each
other) must end in exit code 2 with one line ``masknet: error: <problem>`` on stderr,
before any heavy work: no training, registration, evaluation or benchmark starts (the
functions that do it are tripwires here), nothing is written and every input is left
byte for byte as it was. Refusals by argparse (the option types of ``_common`` and
``_scans``) exit with code 2 too, with one line ``masknet <command>: error: ...`` that
points to ``--help`` instead of printing the usage.

Each case runs in a fresh folder that is also the working directory, so that relative
defaults (``masknet_benchmark``) would land there and be seen.
"""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import pytest

from masknet.cli import main
from masknet.data import bundled_sample_path

RNG = np.random.default_rng(0)
CLOUD = RNG.random((300, 3))


def _surface(n: int, seed: int) -> np.ndarray:
    """A wavy sheet, usable as a scan (load_scans wants >= 1024 points, not on a line)."""
    xy = np.random.default_rng(seed).uniform(-1.5, 1.5, (n, 2))
    return np.column_stack([xy, 0.4 * np.sin(2 * xy[:, 0]) * np.cos(xy[:, 1])])


def _tiny_modelnet(path: Path) -> None:
    """A ModelNet40 .npz with a train split of two shapes of 1024 points."""
    np.savez(
        path,
        train_points=RNG.random((2, 1024, 3)).astype(np.float32),
        train_labels=np.array([0, 1]),
        shape_names=np.array([f"class{i}" for i in range(40)]),
    )


@pytest.fixture
def workdir(tmp_path, monkeypatch, small_masknet_weights) -> dict[str, str]:
    """The inputs every case may use, in ``tmp_path`` (the working directory); returns
    the absolute paths that cases name as ``@weights`` and ``@sample``."""
    import masknet.denoising
    import masknet.evaluation.evaluate
    import masknet.evaluation.scans
    import masknet.experiments
    import masknet.registration
    import masknet.training
    from masknet.models import MaskNet

    def tripwire(*args, **kwargs):
        raise AssertionError("the refusal came after the heavy work had started")

    for owner, name in [
        (masknet.training, "fit"),
        (masknet.registration, "register"),
        (masknet.denoising, "denoise"),
        (MaskNet, "predict_mask_with_scores"),
        (masknet.evaluation.evaluate, "evaluate_masknet"),
        (masknet.evaluation.scans, "evaluate_scans"),
        (masknet.experiments, "run_experiments"),
    ]:
        monkeypatch.setattr(owner, name, tripwire)
    monkeypatch.delenv("MASKNET_DATA", raising=False)  # no case may load the real data set
    monkeypatch.chdir(tmp_path)
    np.savetxt("template.xyz", CLOUD)
    np.save("source.npy", CLOUD[:200] + 0.01)
    np.savetxt("old_inliers.xyz", CLOUD[:250])  # an earlier register's side file
    Path("taken.xyz").mkdir()  # a folder where an output file would go
    Path("scans").mkdir()
    np.save("scans/a.npy", _surface(1100, 1))
    np.save("scans/b.npy", _surface(1100, 2))
    _tiny_modelnet(tmp_path / "tiny.npz")
    Path("RESULTS.md").write_text("# results\n")
    return {"@weights": str(small_masknet_weights), "@sample": str(bundled_sample_path())}


def _argv(command: str, paths: dict[str, str]) -> list[str]:
    return [paths.get(token, token) for token in shlex.split(command)]


def _tree(root: Path) -> dict[str, bytes | None]:
    """Every file (its bytes) and folder (None) under ``root``."""
    return {
        str(p.relative_to(root)): None if p.is_dir() else p.read_bytes()
        for p in sorted(root.rglob("*"))
    }


MASK = "mask template.xyz source.npy -o m.xyz"
REGISTER = "register template.xyz source.npy -o r.xyz"
DENOISE = "denoise template.xyz source.npy -o kept.xyz"
EVALUATE_SCANS = "evaluate --weights @weights --scans scans"
TRAIN = "train -o run"
TRAIN_SCANS = "train -o run --scans scans --modelnet-fraction 0 --val-scans b"

# command line -> the whole message, or its start where it ends in "..."
REFUSALS = {
    # _common.pair_config: the pair options, in every command that makes pairs
    f"{TRAIN} --keep-ratio 0": "keep_ratio must be in (0, 1], got 0.0",
    f"{TRAIN} --model denoise --outliers 1": "outlier_ratio must be in [0, 1), got 1.0",
    "evaluate --data @sample --weights @weights --keep-ratio 1.5": (
        "keep_ratio must be in (0, 1], got 1.5"
    ),
    # _outputs.check_outputs and _common.check_html: outputs refused before any computing
    "register old_inliers.xyz source.npy -o old.xyz": (
        "old_inliers.xyz: is the input old_inliers.xyz; an output never overwrites an "
        "input, give it another name"
    ),
    "mask template.xyz source.npy -o v.png --html v.html": (
        "v.png: named for two outputs; give each output its own name"
    ),
    "denoise template.xyz source.npy -o kept.foo": "kept.foo: cannot write extension '.foo' (supported: ...",
    "mask template.xyz source.npy -o taken.xyz": "taken.xyz: is a directory, not a file",
    "mask template.xyz source.npy -o scans": "scans: is a directory, not a file",
    "mask template.xyz source.npy -o m.xyz --weights runs/modelnet40": (
        "runs/modelnet40: weights file not found (shipped weights go by name: --weights NAME; "
        "in Python, pretrained(NAME))"
    ),
    "mask template.xyz source.npy -o m.xyz --weights nope": (
        "no shipped MaskNet weights named 'nope'; available: ..."
    ),
    "register template.xyz source.npy -o r.xyz --two-sided --weights @weights": (
        "--two-sided needs two-sided MaskNet weights (masknet train --model masknet2); ..."
    ),
    "denoise template.xyz source.npy -o template.xyz/kept.xyz": (
        "template.xyz/kept.xyz: cannot write into template.xyz (not a writable directory)"
    ),
    f"{DENOISE} --html view.png": (
        "view.png: the viewer is an .html file; give a name ending in .html"
    ),
    "show template.xyz source.npy -o view.png": (
        "view.png: the viewer is an .html file; give a name ending in .html"
    ),
    # _scans: the --scans options of train and evaluate
    f"{TRAIN} --scans scans --modelnet-fraction 1.5": (
        "--modelnet-fraction must be in [0, 1], got 1.5"
    ),
    f"{TRAIN} --scans scans --scan-noise -0.1": "--scan-noise must be >= 0, got -0.1",
    f"{TRAIN_SCANS} --scan-points 8": "scan pairs: template_points must be at least 16, got 8",
    f"{EVALUATE_SCANS} --keep-ratio 2": "scan pairs: keep_ratio must be in (0, 1], got 2.0",
    f"{EVALUATE_SCANS} --scan-names a,nope": "scans: no usable scan named nope",
    # ... and those of masknet.data.scans that --scans reaches
    f"{TRAIN} --scans nowhere": "nowhere: no such folder of scans",
    f"{TRAIN} --scans template.xyz": "template.xyz: a file, not a folder of scans",
    f"{TRAIN} --scans scans --val-scans a,b": (
        "every scan is held out for validation; none is left to train on"
    ),
    # benchmark
    "benchmark nope -o bench --results RESULTS.md": (
        "unknown experiment 'nope'; choose from registration, networks, ..."
    ),
    "benchmark registration -o bench --results missing.md": (
        "missing.md: no such results file (--results rewrites one)"
    ),
    # denoise, evaluate, mask
    f"{DENOISE} --threshold 1.5": "--threshold must be in [0, 1], got 1.5",
    f"{EVALUATE_SCANS} --scan-noise -1": "--scan-noise must be >= 0, got -1.0",
    f"{MASK} --threshold -0.5": "--threshold must be in [0, 1] (scores are), got -0.5",
    # register
    f"{REGISTER} --refine -1": "--refine must be >= 0, got -1",
    f"{REGISTER} --two-sided --no-mask": "--two-sided and --no-mask exclude each other",
    f"{REGISTER} --method icp --weights w.safetensors": ("w.safetensors: weights file not found"),
    # train: refused in build_task (before any data) or on the data's size
    f"{TRAIN} --model refine --model-config '{{\"wings\": 2}}'": (
        "refine: RefineMaskNet.__init__() got an unexpected keyword argument 'wings'"
    ),
    f"{TRAIN} --scans scans --model dcp": "--scans trains MaskNet (--model masknet), not dcp",
    f"{TRAIN} --model dcp --model-config '{{\"wings\": 2}}'": (
        "--model-config does not fit dcp: DCP.__init__() got an unexpected keyword argument 'wings'"
    ),
    f"{TRAIN} --model pointnetlk --precision bf16": (
        "--precision bf16 does not suit pointnetlk: registration networks train in fp32 "
        "(PointNetLK's finite-difference Jacobian and the SVDs need it)"
    ),
    f"{TRAIN} --data tiny.npz --num-points 8": "--num-points must be in [16, 1024], got 8",
    f"{TRAIN} --data tiny.npz --num-points 2048": "--num-points must be in [16, 1024], got 2048",
}


@pytest.mark.parametrize("command", list(REFUSALS))
def test_a_refusal_is_one_line_exit_2_and_changes_nothing(workdir, capsys, command):
    root = Path.cwd()
    before = _tree(root)
    code = main(_argv(command, workdir))
    err = capsys.readouterr().err.splitlines()
    assert code == 2
    assert len(err) == 1, err
    expected = "masknet: error: " + REFUSALS[command]
    if expected.endswith("..."):
        assert err[0].startswith(expected[:-3]), err[0]
    else:
        assert err[0] == expected
    assert _tree(root) == before  # nothing written or removed, inputs byte for byte


# command line -> (the option argparse names, its message)
PARSER_REFUSALS = {
    f"{MASK} --k 0": ("--k", "must be at least 1, got 0"),
    "evaluate --pairs x": ("--pairs", "invalid positive_int value: 'x'"),
    "evaluate --seed -1": ("--seed", "must be non-negative, got -1"),
    f"{DENOISE} --max-distance inf": ("--max-distance", "must be a finite number, got inf"),
    f"{TRAIN} --model-config '{{x'": (
        "--model-config",
        "not valid JSON (Expecting property name enclosed in double quotes): {x",
    ),
    f"{TRAIN} --model-config '[1]'": ("--model-config", "must be a JSON object, got [1]"),
    f"{TRAIN} --scans scans --val-scans ,": (
        "--val-scans",
        "expected comma-separated scan names (file stems)",
    ),
    f"{EVALUATE_SCANS} --scan-names ' , '": (
        "--scan-names",
        "expected comma-separated scan names (file stems)",
    ),
    f"{MASK} --k 5 --threshold 0.5": ("--threshold", "not allowed with argument --k"),
}


@pytest.mark.parametrize("command", list(PARSER_REFUSALS))
def test_a_parser_refusal_is_one_error_line(workdir, capsys, command):
    root = Path.cwd()
    before = _tree(root)
    name = command.split()[0]
    with pytest.raises(SystemExit) as info:
        main(_argv(command, workdir))
    err = capsys.readouterr().err.splitlines()
    option, message = PARSER_REFUSALS[command]
    assert info.value.code == 2
    assert err == [
        f"masknet {name}: error: argument {option}: {message} (see masknet {name} --help)"
    ]
    assert _tree(root) == before


@pytest.mark.parametrize(
    "command",
    [
        f"{TRAIN} --data tiny.npz --epochs 1",
        REGISTER,
        DENOISE,
        f"{MASK} --weights @weights",
        "evaluate --data @sample --weights @weights",
        EVALUATE_SCANS,
        "benchmark registration --quick -o bench",
    ],
)
def test_the_tripwires_catch_a_command_that_gets_to_its_work(workdir, command):
    # Good options reach the heavy work: the tripwires above would have caught a refusal
    # that came too late.
    with pytest.raises(AssertionError, match="after the heavy work had started"):
        main(_argv(command, workdir))
