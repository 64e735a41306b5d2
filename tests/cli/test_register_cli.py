"""masknet register through its files: round trips, learned methods, scenes, warnings."""

from __future__ import annotations

import numpy as np
import pytest

from masknet.cli import main
from masknet.data import bundled_sample_path, load_modelnet40
from masknet.evaluation.registration import pose_errors
from masknet.io import read_points


def _read_transform(path) -> np.ndarray:
    assert path.read_text().startswith("# source -> template")
    transform = np.loadtxt(path)  # the header is a comment
    assert transform.shape == (4, 4)
    return transform


@pytest.mark.parametrize("extension", [".ply", ".xyz", ".npy"])
def test_register_round_trip_through_the_files(tmp_path, small_masknet_weights, extension, capsys):
    """A source made from the template by a known motion comes back through the files:
    the transform file maps the source onto the template (template ~= R source + t)
    and the written cloud is the source moved by it."""
    rng = np.random.default_rng(0)
    template = load_modelnet40(bundled_sample_path(), "test").points[5].astype(np.float64)
    angle = np.radians(12.0)
    rot = np.array(
        [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    )
    shift = np.array([0.3, -0.2, 0.1])
    source = rng.permutation(template) @ rot.T + shift  # the template moved: source frame
    np.savetxt(tmp_path / "template.xyz", template)
    np.save(tmp_path / "source.npy", source)
    out = tmp_path / f"registered{extension}"
    args = ["register", str(tmp_path / "template.xyz"), str(tmp_path / "source.npy")]
    assert (
        main(
            [
                *args,
                "-o",
                str(out),
                "--weights",
                str(small_masknet_weights),
                "--max-iterations",
                "50",
                "--method",
                "icp",
            ]
        )
        == 0
    )
    transform = _read_transform(tmp_path / "registered_transform.txt")
    np.testing.assert_allclose(transform[:3, :3], rot.T, atol=1e-5)
    np.testing.assert_allclose(transform[:3, 3], -rot.T @ shift, atol=1e-5)
    moved = np.load(out) if extension == ".npy" else read_points(out)
    np.testing.assert_allclose(moved, source @ transform[:3, :3].T + transform[:3, 3], atol=1e-5)
    inliers = tmp_path / f"registered_inliers{extension}"
    assert inliers.exists()
    printed = capsys.readouterr().out
    assert "Mask-ICP" in printed
    assert "fit: 100.0% of the source points within" in printed
    assert "did it work: likely correct: " in printed


def test_register_warns_when_the_source_does_not_lie_on_the_template(tmp_path, pair_files, capsys):
    template, _, _ = pair_files
    noise = np.random.default_rng(0).uniform(-1, 1, (500, 3))  # no surface at all
    np.save(tmp_path / "noise.npy", noise)
    out = tmp_path / "moved.xyz"
    args = ["register", str(template), str(tmp_path / "noise.npy"), "-o", str(out)]
    assert main(args) == 3  # the outputs are written, and a script can tell
    printed = capsys.readouterr()
    fit = float(printed.out.split("fit: ")[1].split("%")[0])
    assert fit < 50
    assert "did it work: likely wrong: " in printed.out
    assert "warning: the result is likely wrong: " in printed.err
    assert out.exists()
    assert main([*args, "--exit-zero"]) == 0


def test_register_says_when_the_viewpoint_went_unused(tmp_path, pair_files, capsys):
    template, source, _ = pair_files
    out = tmp_path / "moved.xyz"
    args = ["register", str(template), str(source), "-o", str(out), "--viewpoint", "0", "0", "5"]
    assert main(args) == 0  # two clouds of one object: no scene search
    assert "--viewpoint was not used" in capsys.readouterr().err


def test_register_no_mask_writes_no_inliers(tmp_path, pair_files, capsys):
    template, source, _ = pair_files
    out = tmp_path / "moved.xyz"
    assert main(["register", str(template), str(source), "-o", str(out), "--no-mask"]) == 0
    assert out.exists() and (tmp_path / "moved_transform.txt").exists()
    assert not (tmp_path / "moved_inliers.xyz").exists()
    assert capsys.readouterr().out.startswith("default pipeline (auto), no masks:")


# Rotation (deg) and translation bounds: the errors measured on the turned pair (bf16 and
# fp32 masks alike) are in the comments; a result twice as bad fails, and so does no motion.
_LEARNED_BOUNDS = {
    "dcp": (5.0, 0.08),  # 3.02-3.05 deg, 0.048-0.049
    "prnet": (10.0, 0.11),  # 6.15-6.19 deg, 0.061-0.074
    "pcrnet": (6.5, 0.1),  # 3.61-3.75 deg, 0.059
    "rpmnet": (3.5, 0.018),  # 1.89-1.97 deg, 0.009-0.010
}


@pytest.mark.parametrize("method", ["dcp", "prnet", "pcrnet", "rpmnet"])
def test_register_with_learned_networks(tmp_path, turned_pair_files, method, capsys):
    template, source, pair = turned_pair_files
    out = tmp_path / "moved.xyz"
    assert main(["register", str(template), str(source), "-o", str(out), "--method", method]) == 0
    transform = _read_transform(tmp_path / "moved_transform.txt")
    np.testing.assert_allclose(transform[:3, :3] @ transform[:3, :3].T, np.eye(3), atol=1e-6)
    rot, trans = pose_errors(transform[None], pair.transform.double().numpy())
    rot_bound, trans_bound = _LEARNED_BOUNDS[method]
    assert rot[0] < rot_bound and trans[0] < trans_bound, (rot[0], trans[0])
    assert (tmp_path / "moved_inliers.xyz").exists()
    pretty = {"dcp": "DCP", "prnet": "PRNet", "pcrnet": "PCRNet", "rpmnet": "RPM-Net"}[method]
    assert capsys.readouterr().out.startswith(f"Mask-{pretty}:")


def test_register_weights_of_a_network_need_its_method(tmp_path, pair_files, capsys):
    from masknet.models.weights import shipped_weights_path

    template, source, _ = pair_files
    dcp = str(shipped_weights_path("dcp_modelnet40.safetensors"))
    args = ["register", str(template), str(source), "-o", str(tmp_path / "m.xyz")]
    assert main([*args, "--weights", dcp, "--method", "icp"]) == 2
    assert f"{dcp}: holds dcp weights; they need --method dcp" in capsys.readouterr().err
    # One --weights flag for both networks of a Mask-X: the mask's by name, DCP's by file.
    assert main([*args, "--method", "dcp", "--weights", "modelnet40", "--weights", dcp]) == 0
    assert capsys.readouterr().out.startswith("Mask-DCP:")
    assert main([*args, "--method", "dcp", "--weights", dcp, "--weights", dcp]) == 2
    assert "two files of dcp weights" in capsys.readouterr().err
    # The old spelling still works, for one version, and says what to write instead.
    assert main([*args, "--method", "dcp", "--network-weights", dcp]) == 0
    assert capsys.readouterr().err.startswith(
        "masknet: warning: --network-weights is deprecated and goes in the next version; "
        "use --weights FILE\n"
    )


def test_register_bad_source_is_one_line_and_writes_nothing(tmp_path, pair_files, capsys):
    template, _, _ = pair_files
    bad = tmp_path / "flat.xyz"
    np.savetxt(bad, np.zeros((10, 2)))
    out = tmp_path / "moved.ply"
    assert main(["register", str(template), str(bad), "-o", str(out), "--no-mask"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "flat.xyz" in err[0]
    assert list(tmp_path.iterdir()) == [bad]


def test_register_two_sided_drops_source_outliers(tmp_path, capsys):
    rng = np.random.default_rng(3)
    sphere = rng.normal(size=(900, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    part = sphere[sphere[:, 0] > -0.3]
    outliers = rng.uniform(-3, 3, size=(60, 3))
    source = np.concatenate([part + [0.2, 0.0, 0.1], outliers])
    np.save(tmp_path / "t.npy", sphere)
    np.save(tmp_path / "s.npy", source)
    out = tmp_path / "r.npy"
    # --max-points below the source size: the mask is spread back to every source row.
    args = ["register", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "-o", str(out)]
    assert (
        main([*args, "--two-sided", "--max-points", "400", "--html", str(tmp_path / "v.html")]) == 0
    )
    kept = np.loadtxt(tmp_path / "r_source_mask.txt").astype(bool)
    assert kept.shape == (len(source),)
    assert kept[: len(part)].mean() >= 0.9 and (~kept[len(part) :]).mean() >= 0.8
    assert "source kept:" in capsys.readouterr().out
    assert "rejected" in (tmp_path / "v.html").read_text()
    assert main([*args, "--two-sided", "--no-mask"]) == 2


def test_register_robust_from_the_command_line(tmp_path, pair_files, capsys):
    template, source, pair = pair_files
    out = tmp_path / "r.npy"
    assert main(["register", str(template), str(source), "-o", str(out), "--method", "robust"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("robust pipeline:") and "path: " in text
    reported = next(line for line in text.splitlines() if line.startswith("reported by"))
    assert "fitness " in reported and "nan" not in reported  # what did not happen is left out
    transform = np.loadtxt(tmp_path / "r_transform.txt")
    rot = transform[:3, :3] @ pair.transform[0, :3, :3].numpy().T
    assert np.degrees(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1))) < 5


def test_register_finds_an_object_in_a_scene(tmp_path, capsys):
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:4].astype(np.float64)
    grid = np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0], [4, 4, 0]], float)
    scene = np.concatenate(shapes + grid[:, None])  # the object is the second shape, at x = 4
    np.save(tmp_path / "object.npy", shapes[1])
    np.save(tmp_path / "scene.npy", scene)
    out = tmp_path / "r.npy"
    args = ["register", str(tmp_path / "object.npy"), str(tmp_path / "scene.npy"), "-o", str(out)]
    assert main([*args, "--html", str(tmp_path / "v.html")]) == 0
    text = capsys.readouterr().out
    assert "scene search:" in text and "source kept:" in text
    # The scan is named by its file, never by the placeholder of --help.
    assert "regions of scene.npy searched" in text and "SOURCE" not in text
    assert "path: scene search (the template found in scene.npy," in text
    kept = np.loadtxt(tmp_path / "r_source_mask.txt").astype(bool)
    on_object = np.repeat(np.arange(4) == 1, len(shapes[1]))
    assert (kept & on_object).sum() > 0.95 * on_object.sum() and (kept & ~on_object).sum() < 50
    transform = np.loadtxt(tmp_path / "r_transform.txt")
    np.testing.assert_allclose(transform[:3, 3], [-4, 0, 0], atol=0.01)
    assert "found on the object" in (tmp_path / "v.html").read_text()
    assert main([*args, "--scene", "off"]) == 0
    assert "scene search:" not in capsys.readouterr().out
    assert main([*args, "--viewpoint", "0", "0", "10"]) == 0  # a sensor above the grid
    assert "scene search:" in capsys.readouterr().out
    assert main([*args, "--viewpoint", "0", "nan", "1"]) == 2
    assert "viewpoint" in capsys.readouterr().err
    swapped = [
        "register",
        str(tmp_path / "scene.npy"),
        str(tmp_path / "object.npy"),
        "-o",
        str(out),
    ]
    assert main(swapped) == 0
    assert "give the object as TEMPLATE" in capsys.readouterr().err
    # Forced on a scene without the object: it says it found little; the exit status is 0,
    # or 3 where the verdict calls the placement it ended at likely wrong.
    np.save(tmp_path / "other.npy", shapes[0] * [0.2, 3.0, 0.2])
    other = ["register", str(tmp_path / "other.npy"), str(tmp_path / "scene.npy"), "-o", str(out)]
    assert main([*other, "--scene", "on"]) in (0, 3)
    captured = capsys.readouterr()
    assert "scene search:" in captured.out and "may not be in this scan" in captured.err
    assert "under half of other.npy lies on scene.npy" in captured.err


def test_register_says_how_many_rows_it_dropped(tmp_path, pair_files, capsys):
    template, source, _ = pair_files
    points = read_points(source)
    points[[1, 4, 7]] = np.nan
    np.savetxt(tmp_path / "s.xyz", points)
    args = ["register", str(template), str(tmp_path / "s.xyz"), "-o", str(tmp_path / "r.xyz")]
    assert main([*args, "--drop-nonfinite"]) == 0
    assert "3 non-finite rows dropped" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("path", "escalated", "says"),
    [
        ("fast", np.nan, "the fast path's fit passed"),
        ("robust/search", 0.8, "escalated: the fast path's fit was 0.800"),
        ("robust/consensus", 0.8, "the front end's uncertain pose ranked above the search's"),
        ("consensus", np.nan, "the consensus front end"),
        ("robust/correspondences", np.nan, "the search first: the source's principal axes"),
        ("correspondences", np.nan, "method robust"),
    ],
)
def test_the_report_says_why_each_path_ran(path, escalated, says, capsys):
    from masknet.cli._report import report_path

    info = {"path": path, "escalated_fitness": escalated, "source": "x"}
    report_path(info, np.eye(3))
    assert says in capsys.readouterr().out
