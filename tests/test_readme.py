"""The README's examples run as written: every Python block on its own, in a fresh
namespace, and every ``masknet`` command line of its shell blocks parses."""

from __future__ import annotations

import json
import re
import shlex
import textwrap
from pathlib import Path

import numpy as np
import pytest

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.evaluation.registration import pose_errors

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CARTON_TRUTH = ROOT / "docs" / "results" / "carton" / "ground_truth.txt"


def _python_blocks() -> list[str]:
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    return [textwrap.dedent(block) for block in blocks]  # a block in a list is indented


def test_the_readme_has_python_examples():
    blocks = _python_blocks()
    assert len(blocks) >= 3 and any("register(" in b for b in blocks)


def _run_block(index: int, tmp_path: Path, monkeypatch, request) -> dict:
    """Run Python block ``index`` as a reader would, from the repository's root: a fresh
    namespace, files written to a scratch folder, ``../shared/data`` the shared scans."""
    block = _python_blocks()[index]
    root = tmp_path / "masknet"  # stands in for the repository's root
    root.mkdir()
    if "../shared/data" in block:
        scans = request.getfixturevalue("scans_dir")  # skips where they are missing
        (tmp_path / "shared" / "data").mkdir(parents=True)
        (tmp_path / "shared" / "data" / "scans").symlink_to(Path(scans).resolve())
    monkeypatch.chdir(root)
    namespace: dict = {}
    exec(compile(block, f"README.md python block {index}", "exec"), namespace)
    return namespace


@pytest.mark.parametrize("index", range(len(_python_blocks())))
def test_readme_python_example_runs(index, one_thread, tmp_path, monkeypatch, capsys, request):
    namespace = _run_block(index, tmp_path, monkeypatch, request)
    printed = capsys.readouterr().out.splitlines()
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    pair = make_test_pairs(shapes, 1, PairConfig(), seed=3)  # turned 27.4 deg, moved 0.82
    template, source = pair.template[0].double().numpy(), pair.source[0].double().numpy()
    noisy = make_test_pairs(
        shapes, 1, PairConfig(max_angle_deg=0, max_translation=0, outlier_ratio=0.1), seed=4
    )
    clean_template, noisy_scan = (a[0].double().numpy() for a in (noisy.template, noisy.source))
    truth_mask, truth = pair.mask[0].numpy(), pair.transform[0].double().numpy()[None]
    real = noisy.source_mask[0].numpy()  # False for the noisy scan's 72 outliers
    # The bounds below were measured on these pairs: the README's must be them.
    if "template" in namespace and "carton" not in namespace:
        np.testing.assert_array_equal(namespace["template"], template)
        np.testing.assert_array_equal(namespace["source"], source)
    if "noisy_scan" in namespace:
        np.testing.assert_array_equal(namespace["noisy_scan"], noisy_scan)

    def precision(mask: np.ndarray) -> float:
        return (mask & truth_mask).sum() / mask.sum()

    def assert_pose(name: str, rot_bound: float, trans_bound: float) -> None:
        rot, trans = pose_errors(namespace[name].transform[None], truth)
        assert rot[0] < rot_bound and trans[0] < trans_bound, (name, rot[0], trans[0])

    # Whatever the block produced has the documented shapes ...
    if "mask" in namespace:
        assert namespace["mask"].shape == (len(template),)
    if "result" in namespace:
        assert namespace["result"].transform.shape == (4, 4)
    # ... and every block meets at least one check of its values. Bounds: measured on this
    # pair (bf16 and fp32 inference alike) with a margin, and a result twice as bad as
    # measured fails; no motion is 27.4 deg and 0.82 off. Exact results (float error,
    # ~3e-7 deg) are bounded at 1e-4 deg.
    checked = []
    if "scores" in namespace:  # MaskNet.predict / predict_mask (chance precision 0.70)
        top_k = np.zeros(len(template), bool)
        top_k[np.argsort(-namespace["scores"])[: len(source)]] = True
        assert precision(top_k) > 0.935  # measured 0.960 (29 of 717 wrong)
        assert precision(namespace["mask"]) > 0.98  # threshold 0.5: 0.988-0.990 (675-677 kept)
        checked.append("masks")
    if "two_sided" in namespace:
        assert precision(namespace["template_mask"]) > 0.935  # measured 0.961
        assert namespace["source_mask"].mean() >= 0.99  # a clean source: 714 of 717 kept
        # on the scan with 10% outliers: 66 of the 72 removed and 99.4% of real points kept
        _, kept = namespace["two_sided"].predict_masks(clean_template, noisy_scan)
        assert (kept & ~real).sum() <= 10 and kept[real].mean() > 0.985
        checked.append("two-sided masks")
    if "mask_icp" in namespace and "robust" in namespace:  # the registration block
        for name, rot_bound, trans_bound in (
            ("result", 1e-4, 1e-5),  # the default: exact (fast path)
            ("robust", 1e-4, 1e-5),  # exact (correspondences)
            ("mask_icp", 0.12, 0.0023),  # CrossMaskNet's mask: measured 0.0708 deg, 0.0011
            ("plain", 1.9, 0.14),  # 1.16 deg, 0.086
            ("lk", 2.7, 0.07),  # 1.79 deg, 0.036 (the paper's mask: 0.55-0.57 deg, 0.044)
            ("dcp", 5.0, 0.08),  # 2.16 deg, 0.036 (the paper's mask: 3.02-3.05 deg, 0.049)
            ("loop", 0.037, 0.0007),  # 0.0226 deg, 0.00044
        ):
            assert_pose(name, rot_bound, trans_bound)
        assert namespace["result"].info["path"] in ("fast", "robust/correspondences")
        assert not namespace["result"].info["ambiguous"]
        checked.append("poses")
    if "results" in namespace and "poses" in namespace:  # register_many: in order, each right
        assert len(namespace["poses"]) == 2
        for pose in namespace["poses"]:
            rot, trans = pose_errors(pose[None], truth)
            assert rot[0] < 1e-3 and trans[0] < 1e-4, (rot, trans)  # measured: exact
        checked.append("many")
    if "theirs" in namespace:  # Open3D's ICP and masknet's, the same call side by side
        ours, theirs = namespace["ours"], namespace["theirs"]
        np.testing.assert_allclose(ours.transformation, theirs.transformation, atol=1e-7)
        assert abs(float(ours.fitness) - theirs.fitness) < 1e-9  # measured 8e-10 apart
        assert printed == ["1.000 1.000", "True"]  # the block's comments
        checked.append("open3d")
    if "object_points" in namespace:  # the carton found in its scene
        result = namespace["result"]
        rot, trans = pose_errors(result.transform[None], np.loadtxt(CARTON_TRUTH)[None])
        assert rot[0] < 0.5 and trans[0] < 0.002, (rot, trans)  # measured 0.012 deg, 0.16 mm
        assert 12_000 < len(namespace["object_points"]) < 13_500  # 12,729 (the carton's)
        assert printed == ["1.00"]
        checked.append("object found")
    if "quality" in namespace:  # the exact result lies on the template, every point of it
        assert namespace["quality"].fitness == 1  # measured 1.0, inlier RMSE 3.4e-8
        assert namespace["quality"].inlier_rmse < 1e-5
        assert printed[0] == "1.00 within 0.046" and float(printed[1].split()[-1]) < 1e-5
        checked.append("fit")
    if "points" in namespace:  # a round trip through a file
        np.testing.assert_allclose(namespace["points"], source)
        checked.append("files")
    if "unmoved" in namespace:  # did it work: the exact result, and doing nothing (27 deg off)
        assert namespace["check"].verdict == "likely correct", namespace["check"]
        assert namespace["unmoved"].verdict == "likely wrong", namespace["unmoved"]
        assert printed[0].startswith("likely correct - ")
        checked.append("verdicts")
    if "covered" in namespace:  # the loops: three rounds, masks at the pose returned
        result, loop, paper = (namespace[k] for k in ("result", "loop", "paper"))
        assert len(result.rounds) == len(loop.rounds) == len(paper.rounds) == 3
        assert result.method == "auto" and loop.method == "icp"
        # The default's loop: exact, measured 4e-7 deg (ICP pairs with the refiner's wider
        # mask, scores >= 0.5; with the returned mask alone, >= 0.9, it ended 0.019 deg off).
        assert_pose("result", 1e-4, 1e-5)
        assert_pose("loop", 0.037, 0.0007)  # from MaskNet's mask: measured 0.0226 deg, 0.00044
        assert_pose("paper", 0.12, 0.0011)  # measured 0.0715 deg, 0.00053
        assert precision(result.mask) > 0.99 and precision(loop.mask) > 0.99  # both 1.0
        for mask in (result.source_mask, loop.source_mask):  # a clean source: all 717 kept
            assert mask.shape == (len(source),) and mask.mean() >= 0.99
        assert [line.split(":")[0] for line in printed] == ["round 1", "round 2", "round 3"]
        checked.append("loop")
    if "kept" in namespace:  # method="masknet": 6 of the 72 outliers kept, 713 of 717 real
        mask = namespace["kept"].mask
        assert mask.shape == (len(noisy_scan),)
        assert (mask & ~real).sum() <= 10 and mask[real].mean() > 0.985
        checked.append("denoised")
    if "tracked" in namespace:  # tracking: found in the first frame, then followed
        seq = namespace["seq"]
        assert printed[0] == "0 found likely correct"
        # Frame 4 is the sequence's 30-degree jump (jump_at 0.65 of 6 frames): more than a
        # frame's motion, so it is searched near the last pose and found again.
        assert seq.jump == 4
        states = [line.split()[1] for line in printed[1:]]
        assert states == ["tracked", "tracked", "tracked", "refound", "tracked"]
        rot, trans = pose_errors(np.stack(namespace["tracked"]), seq.truth)
        assert rot.max() < 2 and trans.max() < 0.2, (rot, trans)  # translation: template frame
        checked.append("tracked")
    if "prepared" in namespace:  # a template prepared once: the cold calls' poses, exactly
        from masknet import register

        for part, result in zip((source, source[::2]), namespace["results"], strict=True):
            np.testing.assert_array_equal(result.transform, register(template, part).transform)
        checked.append("prepared")
    if "pairs" in namespace:  # pairs to try: the truth moves the source onto the template
        assert namespace["pairs"].template.shape == (8, 1024, 3)
        moved = namespace["source"] @ namespace["truth"][:3, :3].T + namespace["truth"][:3, 3]
        gaps = np.linalg.norm(moved[:, None] - namespace["template"][None], axis=-1).min(1)
        assert len(namespace["source"]) < len(namespace["template"])  # a partial view
        assert gaps.max() < 1e-5  # the view's points are template points, moved
        checked.append("pair")
    assert checked, "this README block meets no check of its values"


def _command_lines() -> list[list[str]]:
    """The arguments of every ``masknet`` command in the README's shell blocks (``\\``
    continuations joined, comments dropped)."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", README.read_text(), flags=re.S):
        for line in textwrap.dedent(block).replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            for i, word in enumerate(words):
                if word == "masknet" or word.endswith("/masknet"):
                    commands.append(words[i + 1 :])
                    break
                if word == "-m" and words[i + 1 : i + 2] == ["masknet.cli"]:
                    commands.append(words[i + 2 :])
                    break
    return commands


def test_every_masknet_command_in_the_readme_parses(capsys):
    """The shell blocks' commands are too slow to run; each is at least one the parser
    takes, in the current spelling (an old spelling would warn)."""
    from masknet.cli import COMMANDS, build_parser

    commands = _command_lines()
    assert len(commands) > 30 and {args[0] for args in commands} >= set(COMMANDS) - {"make-sample"}
    refused = []
    for args in commands:
        try:
            build_parser().parse_args(args)
        except SystemExit:
            refused.append(" ".join(args))
        assert capsys.readouterr().err == "", args
    assert refused == []


def test_the_weights_table_names_each_cards_version():
    # The README's table of shipped weights against each model card's title line.
    rows = re.findall(r"^\| `(\w+)`[^|]*\| (v[\d.]+) \| \[", README.read_text(), flags=re.M)
    weights = README.parent / "src" / "masknet" / "resources" / "weights"
    cards = sorted(p.stem for p in weights.glob("*.md"))
    assert sorted(name for name, _ in rows) == cards
    for name, version in rows:
        title = (weights / f"{name}.md").read_text().splitlines()[0]
        assert title == f"# Model card: `{name}` {version}", (name, version, title)


def test_the_demo_precision_in_the_readme_is_the_shipped_weights(tmp_path, one_thread):
    # `make demo`'s figure, recomputed: the shipped weights on the bundled sample's pairs.
    from masknet.cli import main

    text = README.read_text()
    stated = float(re.search(r"top-k precision (0\.\d+) with the shipped weights", text)[1])
    assert main(["demo", "-o", str(tmp_path)]) == 0
    metrics = json.loads((tmp_path / "metrics.json").read_text())["metrics"]
    measured = metrics["top-k (k=M)"]
    assert abs(measured["precision"] - stated) < 0.0015, (measured["precision"], stated)


def test_the_readme_lists_every_path_of_the_default():
    # The Registration section's list of info["path"] values, against the code's own list.
    from masknet.registration.stages.auto import PATHS

    text = README.read_text()
    listed = text.split('`result.info["path"]` says which ran:', 1)[1].split("), and", 1)[0]
    assert set(re.findall(r'`"([^"]+)"`', listed)) >= set(PATHS), listed
