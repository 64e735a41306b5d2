"""Nothing lost: no command overwrites an input (one rule, checked before any work), the
answer is written whatever a side output's format, and an interrupt says what is on disk
and leaves no folder it made."""

from __future__ import annotations

import contextlib
import types
import warnings

import numpy as np
import pytest

import masknet.registration.many as many
from masknet.cli import main
from masknet.cli._common import EXIT_INTERRUPTED, EXIT_LIKELY_WRONG, EXIT_REFUSED
from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs

CLASH = "an output never overwrites an input"


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray]:
    shapes = load_modelnet40(bundled_sample_path(), "test").points[:1]
    made = make_test_pairs(shapes, 1, PairConfig(), seed=1)
    return made.template[0].numpy().astype(np.float64), made.source[0].numpy().astype(np.float64)


@pytest.fixture()
def saved(tmp_path, pair):
    """The pair as t.npy and s.npy in ``tmp_path``, which it returns."""
    np.save(tmp_path / "t.npy", pair[0])
    np.save(tmp_path / "s.npy", pair[1])
    return tmp_path


def _batch(folder, *more: str) -> list[str]:
    """register-many of ``folder``'s t.npy against its s.npy, and ``more``."""
    return ["register-many", "--template", str(folder / "t.npy"), "--sources", str(folder / "s.npy"), *more]  # fmt: skip


@pytest.fixture()
def no_batch_work(monkeypatch):
    """register-many's pool, which would register: a refusal must come before it."""

    def no_pool(*args, **kwargs):
        raise AssertionError("the batch started: the refusal came after work started")

    monkeypatch.setattr(many, "executor", no_pool)


@pytest.fixture()
def in_process(monkeypatch):
    """register-many's pairs run here, one after the other (no worker processes)."""

    def run_here(jobs, options, pool, done):
        for job in jobs:
            done(many.run_job(job, options))

    monkeypatch.setattr(many, "executor", lambda *a, **k: contextlib.nullcontext())
    monkeypatch.setattr(many, "run_jobs", run_here)


def _interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def _refused(code: int, err: str, *words: str) -> None:
    lines = err.strip().splitlines()
    assert code == EXIT_REFUSED and len(lines) == 1, lines
    assert all(w in lines[0] for w in words), lines[0]


# register-many: the user's cases, then the links


def test_a_pair_file_named_as_a_result_is_refused(
    tmp_path, pair, capsys, sha256_of, no_batch_work, monkeypatch
):
    np.save(tmp_path / "ref.npy", pair[0])
    np.savetxt(tmp_path / "w_transform.txt", pair[1])  # 717 points, named as w's transform
    (tmp_path / "pairs.txt").write_text("ref.npy w_transform.txt w\n")
    before = sha256_of(tmp_path)
    monkeypatch.chdir(tmp_path)
    code = main(["register-many", "--list", "pairs.txt", "-o", "."])
    _refused(code, capsys.readouterr().err, "w_transform.txt: is the input", CLASH, "NAME")
    assert sha256_of(tmp_path) == before


def test_the_list_file_named_as_the_summary_is_refused(
    tmp_path, saved, capsys, sha256_of, no_batch_work
):
    (tmp_path / "summary.csv").write_text("t.npy s.npy\n")
    before = sha256_of(tmp_path)
    code = main(["register-many", "--list", str(tmp_path / "summary.csv"), "-o", str(tmp_path)])
    _refused(code, capsys.readouterr().err, "summary.csv: is the input", CLASH, "another folder")
    assert sha256_of(tmp_path) == before


@pytest.mark.parametrize(
    ("result", "kind"),
    [("s.json", "symbolic link"), ("s_transform.txt", "hard link"), ("summary.csv", "hard link")],
)
def test_a_result_linked_to_an_input_is_refused(
    tmp_path, saved, capsys, sha256_of, no_batch_work, result, kind
):
    (tmp_path / "pairs.txt").write_text("t.npy s.npy\n")
    out = tmp_path / "out"
    out.mkdir()
    # An earlier result that is a link to an input: writing through it would change the input.
    target = tmp_path / ("pairs.txt" if result.endswith(".csv") else "s.npy")
    if kind == "symbolic link":
        (out / result).symlink_to(target)
    else:
        (out / result).hardlink_to(target)
    before = sha256_of(tmp_path)
    code = main(["register-many", "--list", str(tmp_path / "pairs.txt"), "-o", str(out)])
    _refused(code, capsys.readouterr().err, f"{result}: is the input", CLASH)
    assert sha256_of(tmp_path) == before


def test_an_output_folder_that_is_a_file_is_one_line(
    tmp_path, saved, capsys, sha256_of, no_batch_work
):
    (tmp_path / "results").write_text("a file, not a folder\n")
    before = sha256_of(tmp_path)
    code = main(_batch(tmp_path, "-o", str(tmp_path / "results")))
    _refused(code, capsys.readouterr().err, "results: is a file", "folder")
    assert sha256_of(tmp_path) == before


def test_a_start_matrix_named_as_an_output_is_refused(
    tmp_path, saved, capsys, sha256_of, no_batch_work, monkeypatch
):
    """Refining an earlier result into the same name would overwrite the start it read."""
    import masknet.io

    def no_work(*args, **kwargs):
        raise AssertionError("an input was read: the refusal came after work started")

    monkeypatch.setattr(masknet.io, "read_points_with_rows", no_work)
    (tmp_path / "out").mkdir()
    np.savetxt(tmp_path / "m_transform.txt", np.eye(4))
    np.savetxt(tmp_path / "out" / "s_transform.txt", np.eye(4))
    before = sha256_of(tmp_path)
    pair = [str(tmp_path / "t.npy"), str(tmp_path / "s.npy")]
    start = ["--init", str(tmp_path / "m_transform.txt")]
    code = main(["register", *pair, "-o", str(tmp_path / "m.npy"), *start])
    _refused(code, capsys.readouterr().err, "m_transform.txt: is the input", CLASH)
    code = main(_batch(tmp_path, "-o", str(tmp_path / "out"), "--init", str(tmp_path / "out" / "s_transform.txt")))  # fmt: skip
    _refused(code, capsys.readouterr().err, "s_transform.txt: is the input", CLASH)
    assert sha256_of(tmp_path) == before


# the other commands that read files given by name


def test_the_other_commands_refuse_an_output_that_is_an_input(
    tmp_path, capsys, sha256_of, small_masknet_weights
):
    from masknet.io import write_points

    write_points(tmp_path / "a.xyz", np.random.default_rng(0).random((50, 3)))
    (tmp_path / "view.html").symlink_to(tmp_path / "a.xyz")
    weights = tmp_path / "w.safetensors"
    weights.write_bytes(small_masknet_weights.read_bytes())
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "best.safetensors").hardlink_to(weights)
    (tmp_path / "d.npz").write_bytes(b"ModelNet40, as far as this test goes")
    before = sha256_of(tmp_path)
    calls = {
        "show": ["show", str(tmp_path / "a.xyz"), "-o", str(tmp_path / "view.html")],
        "evaluate": ["evaluate", "--weights", str(weights), "-o", str(weights)],
        "train": ["train", "-o", str(tmp_path / "run"), "--init", str(weights)],
        "make-sample": ["make-sample", "--data", str(tmp_path / "d.npz"), "-o", str(tmp_path / "d.npz")],
    }  # fmt: skip
    for command, argv in calls.items():
        _refused(main(argv), capsys.readouterr().err, "is the input", CLASH)
        assert sha256_of(tmp_path) == before, command


# the answer is written whatever the format of a side output


@pytest.mark.parametrize("ext", [".npy", ".ply", ".pcd"])
def test_mixed_units_give_one_exit_status_and_the_transform_in_every_format(
    tmp_path, pair, capsys, ext, o3d
):
    """Template in metres, source in millimetres: no template point is an inlier, and
    an empty cloud cannot be a .ply or .pcd; the inliers are skipped, not the answer."""
    np.savetxt(tmp_path / "template.xyz", pair[0])
    np.save(tmp_path / "source.npy", 1000 * pair[1])
    out = tmp_path / f"out{ext}"
    code = main(["register", str(tmp_path / "template.xyz"), str(tmp_path / "source.npy"), "-o", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == EXIT_LIKELY_WRONG, err
    assert np.loadtxt(tmp_path / "out_transform.txt").shape == (4, 4) and out.exists()
    if ext != ".npy":
        assert f"out_inliers{ext}: cannot write an empty cloud" in err and "skipped" in err
        assert not (tmp_path / f"out_inliers{ext}").exists()


@pytest.mark.parametrize("ext", [".npy", ".ply"])
def test_nothing_kept_is_the_same_outcome_in_every_format(tmp_path, pair, capsys, ext, o3d):
    """denoise (and mask) keep no point: the mask is the answer, in every format."""
    np.savetxt(tmp_path / "template.xyz", pair[0])
    np.savetxt(tmp_path / "far.xyz", pair[1] + 100.0)  # nothing near the template
    out = tmp_path / f"kept{ext}"
    code = main(["denoise", str(tmp_path / "template.xyz"), str(tmp_path / "far.xyz"), "-o", str(out), "--max-distance", "0.01"])  # fmt: skip
    assert code == 0
    assert np.loadtxt(tmp_path / "kept_mask.txt").sum() == 0
    assert out.exists() == (ext == ".npy")  # an empty .ply cannot be written: said, not fatal
    assert (ext == ".ply") == ("kept.ply: cannot write an empty cloud" in capsys.readouterr().err)


# interrupts


def test_an_interrupt_after_the_outputs_are_written_says_so(tmp_path, saved, capsys, monkeypatch):
    import masknet.cli.register as register

    monkeypatch.setattr(register, "print_result", _interrupt)
    out = tmp_path / "moved.xyz"
    assert (
        main(["register", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "-o", str(out)]) == 130
    )
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("masknet: interrupted; the outputs were written: ")
    assert f"{tmp_path / 'moved_transform.txt'}" in last and out.exists()


def test_an_interrupt_while_writing_leaves_no_folder_it_made(tmp_path, saved, capsys, monkeypatch):
    import masknet.io

    monkeypatch.setattr(masknet.io, "write_points", _interrupt)
    (tmp_path / "was_there").mkdir()  # empty, and not this run's: it stays
    inputs = [str(tmp_path / "t.npy"), str(tmp_path / "s.npy")]
    for out in (tmp_path / "new" / "deeper" / "m.xyz", tmp_path / "was_there" / "m.xyz"):
        assert main(["register", *inputs, "-o", str(out)]) == EXIT_INTERRUPTED
        assert capsys.readouterr().err.strip().splitlines()[-1] == "masknet: interrupted"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.npy", "t.npy", "was_there"]
    assert list((tmp_path / "was_there").iterdir()) == []


def test_a_batch_interrupted_before_any_result_leaves_no_folder(
    tmp_path, saved, capsys, monkeypatch
):
    monkeypatch.setattr(many, "executor", lambda *a, **k: contextlib.nullcontext())
    monkeypatch.setattr(many, "run_jobs", _interrupt)
    assert main(_batch(tmp_path, "-o", str(tmp_path / "results"))) == EXIT_INTERRUPTED
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("masknet: interrupted; 0 of 1 pairs are finished")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.npy", "t.npy"]


def test_a_batch_interrupted_after_its_results_says_so(
    tmp_path, saved, capsys, monkeypatch, in_process
):
    import masknet.cli.register_many as register_many

    monkeypatch.setattr(register_many, "_report", _interrupt)
    out = tmp_path / "results"
    assert main(_batch(tmp_path, "--method", "icp", "-o", str(out))) == EXIT_INTERRUPTED
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last == f"masknet: interrupted; the results are written in {out}"
    assert sorted(p.name for p in out.iterdir()) == ["s.json", "s_transform.txt", "summary.csv"]


def test_a_rerun_with_other_options_says_it_replaces_the_earlier_results(
    tmp_path, saved, capsys, in_process
):
    out = tmp_path / "results"
    args = _batch(tmp_path, "-o", str(out), "--method", "icp")
    main(args)
    assert "replaced" not in capsys.readouterr().err
    main(args)  # the same options: nothing to do, nothing replaced
    assert "replaced" not in capsys.readouterr().err
    main([*args, "--iterations", "2"])
    err = capsys.readouterr().err
    assert f"earlier results in {out} made with other files or options are replaced: 1 of 1" in err


def test_an_interrupt_as_the_command_returns_still_gets_its_line(capsys, monkeypatch):
    """Ctrl-C in the CLI's own teardown, after a command finished, is one line and 130."""
    import masknet.cli

    class Interrupted(contextlib.AbstractContextManager):
        def __init__(self, *args, **kwargs) -> None:
            pass

        def __exit__(self, *exc):
            raise KeyboardInterrupt

    # The CLI's own view of the warnings module; pytest's stays as it is.
    own = types.SimpleNamespace(
        catch_warnings=Interrupted,
        simplefilter=lambda *a, **k: None,
        showwarning=warnings.showwarning,
    )
    monkeypatch.setattr(masknet.cli, "warnings", own)
    monkeypatch.setattr(masknet.cli.make_sample, "run", lambda args: 0)
    try:
        code = main(["make-sample", "-o", "never.npz"])
    except KeyboardInterrupt:  # not pytest's own Ctrl-C: that would end the whole session
        pytest.fail("the interrupt escaped the CLI's guard")
    assert code == EXIT_INTERRUPTED
    assert capsys.readouterr().err == "masknet: interrupted\n"


# A path through a folder not made yet, and back: the writer makes the folder and lands on
# the input, so the rule resolves the path before it compares.


@pytest.mark.parametrize("through", ["new/../", "have/a/b/../../../"])
def test_an_output_through_a_missing_folder_and_back_is_refused(
    saved, capsys, sha256_of, monkeypatch, through
):
    (saved / "have").mkdir()
    before = sha256_of(saved)
    monkeypatch.chdir(saved)
    for command in (
        ["register", "t.npy", "s.npy", "-o", f"{through}s.npy"],
        ["mask", "t.npy", "s.npy", "-o", f"{through}s.npy"],
        ["denoise", "t.npy", "s.npy", "-o", f"{through}t.npy"],
    ):
        _refused(main(command), capsys.readouterr().err, CLASH)
    assert sha256_of(saved) == before  # nothing written, no folder made


def test_a_batch_through_a_missing_folder_and_back_is_refused(
    saved, capsys, sha256_of, no_batch_work, monkeypatch
):
    (saved / "summary.csv").write_text("t.npy s.npy y\n")
    before = sha256_of(saved)
    monkeypatch.chdir(saved)
    _refused(main(["register-many", "--list", "summary.csv", "-o", "new/.."]), capsys.readouterr().err, CLASH)  # fmt: skip
    assert sha256_of(saved) == before


@pytest.mark.parametrize("output", [".", "..", "", "/", "out/"])
def test_an_output_that_names_no_file_is_refused_in_one_line(saved, capsys, output):
    for command in ("register", "mask"):
        code = main([command, str(saved / "t.npy"), str(saved / "s.npy"), "-o", output])
        _refused(code, capsys.readouterr().err, "names a folder")


def test_a_batch_into_a_dangling_link_is_refused_before_any_work(saved, capsys, no_batch_work):
    (saved / "dangling").symlink_to(saved / "nowhere")
    code = main(_batch(saved, "-o", str(saved / "dangling")))
    _refused(code, capsys.readouterr().err, "a link to nothing")


def test_evaluate_refuses_a_folder_or_a_file_as_parent_before_it_evaluates(
    saved, capsys, monkeypatch
):
    import masknet.evaluation.evaluate as evaluation

    def no_work(*args, **kwargs):
        raise AssertionError("the evaluation ran before the refusal")

    monkeypatch.setattr(evaluation, "evaluate_masknet", no_work)
    data = str(bundled_sample_path())
    for output in (str(saved), str(saved / "t.npy" / "e.json")):
        code = main(["evaluate", "--data", data, "--pairs", "2", "-o", output])
        _refused(code, capsys.readouterr().err, str(saved))
