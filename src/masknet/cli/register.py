"""``masknet register``: Mask-X (or plain X) from files; writes the moved source, the 4x4
transform and the inlier template."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from masknet._atomic import write_all
from masknet.cli._common import (
    EXIT_LIKELY_WRONG,
    add_cloud_arguments,
    add_file_options,
    add_model_options,
    add_old_spelling,
    at_least_three,
    check_html,
    exit_codes_text,
    finite_float,
    init_option,
    load_model,
    positive_int,
    progress,
    start_files,
)
from masknet.cli._outputs import check_outputs, output_file
from masknet.cli._pictures import registration_views
from masknet.cli._report import print_result, report_path, shown_numbers
from masknet.errors import MaskNetError
from masknet.registration.terms.methods import METHOD_TITLES, METHODS, PIPELINES

if TYPE_CHECKING:  # heavy imports stay out of ``masknet --help``
    from collections.abc import Callable

    import numpy as np

    from masknet.models import MaskNet
    from masknet.registration.judge.assessment import Assessment
    from masknet.registration.stages.scene import SceneSearch
    from masknet.registration.terms.result import RegistrationResult


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Add ``register`` to the ``masknet`` subparsers."""
    p = subparsers.add_parser(
        "register",
        help="align SOURCE to TEMPLATE and write the moved source",
        description="align SOURCE to TEMPLATE (Mask-X, or plain X with --no-mask); write the "
        "moved source, the 4x4 transform and the inlier template",
        epilog=exit_codes_text(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_cloud_arguments(p, source_help="partial cloud of the same object, any pose")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="the registered source (format from the extension); beside it "
        "<stem>_transform.txt (4x4, source -> template) and, with a mask, "
        "<stem>_inliers<ext> (the template points used)",
    )
    _add_method_options(p)
    _add_round_options(p)
    _add_mask_options(p)
    p.add_argument(
        "--exit-zero",
        action="store_true",
        help="exit 0 even when the verdict is likely wrong (default: exit 3)",
    )
    _add_scene_options(p)
    add_file_options(p)
    add_model_options(
        p,
        default_weights=None,
        default_text="modelnet40_small for the default method's fast path; "
        "crossmasknet_modelnet40 for one round of --method icp or a learned method "
        "(modelnet40: the paper's MaskNet); with --two-sided, --iterations above 1 or --method robust the "
        "two-sided scans; give it twice for a learned --method: the mask's and the "
        "network's file (masknet train --model NAME)",
        several=True,
    )
    add_old_spelling(p, "--network-weights", "--weights FILE", "weights", append=True)


def _add_method_options(p: argparse.ArgumentParser) -> None:
    """``--method``, ``--no-mask`` and ``--two-sided``: which registration, masked how."""
    p.add_argument(
        "--method",
        choices=list(METHODS),
        default=None,
        help="auto (the default; no other flag changes it, and a flag it does not take is "
        "refused naming the method that does): one round of Mask-ICP, its fit checked, and robust "
        "where the fit says it may be wrong; robust: the coarse-to-fine pipeline (FPFH "
        "correspondence hypotheses, then the two-sided mask and rotation hypotheses; any "
        "rotation, outliers); icp: the paper's Mask-ICP; a learned network (pointnetlk, dcp, "
        "prnet, pcrnet, rpmnet; shipped weights unless --weights names a file of one); or "
        "Open3D's icp / "
        "RANSAC / FGR on FPFH",
    )
    p.add_argument("--no-mask", action="store_true", help="plain X instead of Mask-X")
    p.add_argument(
        "--two-sided",
        action="store_true",
        help="mask both clouds with the two-sided MaskNet (shipped masknet2_scans, or "
        "--weights from masknet train --model masknet2): outliers and clutter in SOURCE "
        "are dropped before registering; writes <stem>_source_mask.txt, one 0/1 per "
        "source point",
    )


def _add_round_options(p: argparse.ArgumentParser) -> None:
    """``--iterations``, ``--refine-masks``, ``--max-iterations`` and ``--option``: the
    rounds and the method's own settings."""
    p.add_argument(
        "--iterations",
        type=positive_int,
        default=1,
        help="rounds of mask -> register (default 1); from round 2 on the masks are refined "
        "on the pair as the last round left it (--refine-masks). With auto or robust, round 1 "
        "is that pipeline's answer",
    )
    p.add_argument(
        "--refine-masks",
        choices=["nearest", "learned", "network"],
        default=None,
        help="the masks of rounds >= 2: learned (the default: the refinement network "
        "refinemask_scans), nearest (the nearest-neighbour rule, about twice as fast), network "
        "(MaskNet again in every round, each cloud centred on its own: the paper's loop)",
    )
    p.add_argument(
        "--max-iterations",
        type=positive_int,
        default=None,
        help="iterations of the method per round (default: 10 for ICP and PointNetLK, "
        "as the paper; the learned networks' own: dcp 1, prnet 3, pcrnet 8, rpmnet 5)",
    )
    p.add_argument(
        "--option",
        action="append",
        default=[],
        type=method_option,
        metavar="NAME=VALUE",
        help="any field of the method's options, as in Python (repeatable), e.g. --option "
        "accept_fitness=0.95 --option hypotheses=12 for auto and robust, --option "
        "relative_rmse=1e-6 for icp (masknet.registration.terms.options lists them); the flags "
        "above win over the same name here",
    )


def _add_mask_options(p: argparse.ArgumentParser) -> None:
    """Round 1's mask (``--k`` or ``--mask-threshold``; the former ``--threshold``), the
    plain-ICP end (``--refine``), each round's start (``--init``) and the pair cut-off."""
    mask = p.add_mutually_exclusive_group()
    mask.add_argument(
        "--k",
        type=positive_int,
        help="round 1's mask: the K template points MaskNet scores highest (default: as many "
        "as the source has points)",
    )
    mask.add_argument(
        "--mask-threshold",
        type=finite_float,
        metavar="EPS",
        help="round 1's mask: the template points scoring at least EPS (the paper's rule; "
        "Open3D's threshold, the pair cut-off, is --max-correspondence-distance)",
    )
    mask.add_argument(  # the former name, read as Open3D's threshold by some: one version more
        "--threshold", type=finite_float, dest="deprecated_threshold", help=argparse.SUPPRESS
    )

    p.add_argument(
        "--refine",
        type=int,
        default=0,
        metavar="N",
        help="end with N iterations of plain ICP on the whole template (default 0)",
    )
    p.add_argument(
        "--init",
        type=init_option,
        default="centroid",
        metavar="{centroid,identity,FILE}",
        help="start of each round: centroid (default; the source centroid onto the centroid "
        "of the template points in use), identity (no motion), or FILE, a 4x4 source -> "
        "template matrix to start from (Open3D's init; text as <stem>_transform.txt, or .npy), "
        "for every method",
    )
    p.add_argument(
        "--max-correspondence-distance",
        type=finite_float,
        metavar="D",
        help="the pair cut-off of ICP and the pipelines, in the clouds' units (Open3D's "
        "max_correspondence_distance; default: 1.5 template spacings for the fit, the "
        "method's own rule for ICP)",
    )


def _add_scene_options(p: argparse.ArgumentParser) -> None:
    """``--max-points``, ``--scene`` and ``--viewpoint``: large clouds and scene search."""
    p.add_argument(
        "--max-points",
        type=at_least_three,
        default=1024,
        help="larger clouds are farthest-point sampled to this for the networks and "
        "ICP; the transform is applied to the full source (default 1024, at least 3)",
    )
    p.add_argument(
        "--scene",
        choices=["auto", "on", "off"],
        default="auto",
        help="find TEMPLATE, a small object, in SOURCE, a large scan, before registering: "
        "auto (default) when SOURCE is at least 3 times as spread out as TEMPLATE (median "
        "distance from the median point); the scene points "
        "found on the object go to <stem>_source_mask.txt",
    )
    p.add_argument(
        "--viewpoint",
        nargs=3,
        type=float,
        metavar=("X", "Y", "Z"),
        help="with a scene search: the sensor's position in SOURCE's coordinates (0 0 0 for "
        "a depth frame in camera coordinates); then only the side of TEMPLATE facing it "
        "must lie on the scan, so a full 360-degree model can be found",
    )


def scene_option(
    args: argparse.Namespace, template: np.ndarray, source: np.ndarray
) -> bool | SceneSearch | None:
    """``register``'s ``scene`` argument from ``--scene`` and ``--viewpoint``: None, a bool,
    or the search's options (a viewpoint with ``--scene auto`` applies where the clouds
    call for a search)."""
    from masknet.registration.stages.scene import SceneSearch, is_scene

    choice = {"auto": None, "on": True, "off": False}[args.scene]
    if args.viewpoint is None or choice is False:
        return choice
    search = SceneSearch(viewpoint=tuple(args.viewpoint))
    search.check()
    return search if choice or is_scene(template, source, search) else None


def run(args: argparse.Namespace) -> int:
    """Register; write the outputs all-or-nothing and print what the method reported.
    Returns the exit status (:data:`masknet.cli._common.EXIT_CODES`)."""

    from masknet.io import read_points_with_rows
    from masknet.registration import assess_registration, register

    if args.refine < 0:
        raise MaskNetError(f"--refine must be >= 0, got {args.refine}")
    out = output_file(args.output)
    # The side files a run owns: the transform always, the inliers with a mask, the source
    # mask when the result masks the source (a loop, two-sided MaskNet, robust, scene
    # search). Those a run does not write are removed with its outputs, so that an earlier
    # run's never look like part of this one.
    derived = [
        out.with_name(out.stem + "_transform.txt"),
        out.with_name(out.stem + "_inliers" + out.suffix),
        out.with_name(out.stem + "_source_mask.txt"),
    ]
    inputs = [args.template, args.source, *start_files(args)]
    inputs += [w for w in args.weights if Path(w).is_file()]  # shipped names are no files
    check_outputs([out, *derived] + check_html(args.html), inputs=inputs)
    with progress(f"reading {args.template}"):
        template, template_rows = read_points_with_rows(
            args.template, drop_nonfinite=args.drop_nonfinite
        )
    with progress(f"reading {args.source}"):
        source, source_rows = read_points_with_rows(args.source, drop_nonfinite=args.drop_nonfinite)
    from masknet.registration.stages.scene import is_scene

    if args.scene != "off" and is_scene(source, template):
        print(
            "masknet: warning: TEMPLATE is at least 3 times as spread out as SOURCE; to find "
            "an object in a scan, give the object as TEMPLATE and the scan as SOURCE",
            file=sys.stderr,
        )
    if args.two_sided and args.no_mask:
        raise MaskNetError("--two-sided and --no-mask exclude each other")
    method_named = args.method is not None  # as register's method=None: the same refusals
    args.method = args.method or "auto"
    mask_threshold = threshold_option(args)
    args.weights, network_weights = split_weights(args.weights, args.method)
    model = _model(args)
    options = _method_options(args, network_weights)
    with progress(f"registering {len(source):,} onto {len(template):,} points ({args.method})"):
        result = register(
            template,
            source,
            method=args.method if method_named else None,
            use_mask=not args.no_mask,
            iterations=args.iterations,
            model=model,
            precision=args.precision,
            init=args.init,
            refine_iterations=args.refine,
            max_points=args.max_points,
            k=args.k,
            mask_threshold=mask_threshold,
            **({} if args.refine_masks is None else {"refine_masks": args.refine_masks}),
            scene=scene_option(args, template, source),
            **options,
        )
    name = _method_name(args)
    on_object = source if result.source_mask is None else source[result.source_mask]
    check = assess_registration(template, on_object, result.transform)
    writers = _writers(args, out, (template, source), (template_rows, source_rows), result, check)
    with progress("writing the outputs"):
        removed = write_all(writers, stale=derived, optional=[p for p, _ in writers[2:]])
    written = [p for p, _ in writers if p.exists()]  # a skipped side output is not there
    try:
        _report(args, name, template, source, source_rows, result, check)
        print(f"wrote {', '.join(map(str, written))}")
        if removed:
            print(f"removed {', '.join(map(str, removed))} (an earlier run's; this run wrote none)")
    except KeyboardInterrupt:  # the answer is on disk: say so, and still exit 130
        raise KeyboardInterrupt(
            f"the outputs were written: {', '.join(map(str, written))}"
        ) from None
    return EXIT_LIKELY_WRONG if check.verdict == "likely wrong" and not args.exit_zero else 0


def _model(args: argparse.Namespace) -> MaskNet | None:
    """The MaskNet the options name; None where none is named (``register`` then picks the
    shipped default itself: the paper's MaskNet for one round, the two-sided network for a
    loop)."""
    from masknet.models.two_sided import TwoSidedMaskNet

    named = args.two_sided or args.weights
    model = load_model(args, two_sided=args.two_sided) if named and not args.no_mask else None
    if args.two_sided and model is not None and not isinstance(model, TwoSidedMaskNet):
        raise MaskNetError(
            f"--two-sided needs two-sided MaskNet weights (masknet train --model masknet2); "
            f"{args.weights} holds a paper MaskNet, which masks the template only"
        )
    return model


def _method_options(args: argparse.Namespace, network: object | None) -> dict:
    """The method's options: ``--option``, and the flags, which win over the same name;
    ``network``: a learned method's own network, from ``--weights`` (or None)."""

    options = dict(args.option)
    if args.max_iterations is not None:
        options["max_iterations"] = args.max_iterations
    if args.max_correspondence_distance is not None:
        options["max_correspondence_distance"] = args.max_correspondence_distance
    if network is not None:
        options["network"] = network
    return options


def _method_name(args: argparse.Namespace) -> str:
    """The method as the report and the picture name it."""
    if args.method in PIPELINES:  # they choose their own stages; the path line says which
        name = "default pipeline (auto)" if args.method == "auto" else f"{args.method} pipeline"
        return name + (", no masks" if args.no_mask else "")
    return ("" if args.no_mask else "Mask-") + METHOD_TITLES[args.method]


def _writers(
    args: argparse.Namespace,
    out: Path,
    clouds: tuple[np.ndarray, np.ndarray],
    rows: tuple[np.ndarray, np.ndarray],
    result: RegistrationResult,
    check: Assessment,
) -> list[tuple[Path, Callable[[Path], None]]]:
    """The writers of ``register``'s outputs, for :func:`~masknet._atomic.write_all`: the
    answer first (the transform, then the moved source), then the side outputs (inliers,
    source mask, views), which may be skipped. ``clouds``: template (N, 3) and source
    (M, 3) as read; ``rows``: the input rows each kept."""
    from masknet.io import read_point_attributes, write_mask, write_points, write_text_atomic
    from masknet.io_checks import over_rows
    from masknet.registration.many import transform_text
    from masknet.viewer import scene_layers, view_writers

    (template, source), (template_rows, source_rows) = clouds, rows
    moved = source @ result.R.T + result.t
    # '#' comments, so that np.loadtxt reads the 4x4 matrix as it is.
    text = transform_text(result.transform)
    # Colour and normals of .ply/.pcd inputs go on to the outputs (normals turned too).
    carried = read_point_attributes(args.source, out).take(source_rows).turned(result.R)
    writers = [
        (out.with_name(out.stem + "_transform.txt"), lambda p: write_text_atomic(p, text)),
        (out, lambda p: write_points(p, moved, *carried)),
    ]
    if result.mask is not None:
        inliers_path = out.with_name(out.stem + "_inliers" + out.suffix)
        inliers = read_point_attributes(args.template, out).take(template_rows).take(result.mask)
        writers.append((inliers_path, lambda p: write_points(p, template[result.mask], *inliers)))
    if result.source_mask is not None:
        source_mask = over_rows(result.source_mask, source_rows)
        writers.append(
            (out.with_name(out.stem + "_source_mask.txt"), lambda p: write_mask(p, source_mask))
        )
    if args.html:  # written with the others; the verdict on the picture
        title = f"{_method_name(args)}: {Path(args.source).name} -> {Path(args.template).name}"
        if result.scene is not None:  # a scene: the object and its surroundings
            caption = f"did it work: {check.verdict}: {check.reason}"
            layers = scene_layers(template, moved, result.source_mask)
            writers += view_writers(args.html, layers, title, caption=caption)
        else:
            writers += registration_views(args.html, template, source, moved, result, check, title)
    return writers


def _report(
    args: argparse.Namespace,
    name: str,
    template: np.ndarray,
    source: np.ndarray,
    source_rows: np.ndarray,
    result: RegistrationResult,
    check: Assessment,
) -> None:
    """Print what the method reported, the verdict and its warnings."""
    from masknet.registration.terms.options import DEFAULT_SPACINGS

    print_result(args, name, template, source, source_rows, result)
    report_path(result.info, result.R, Path(args.source).name)
    print("reported by the method: " + shown_numbers(result.info))
    print(f"did it work: {check.verdict}: {check.reason}")
    print(
        f"fit: {check.fitness:.1%} of the {'kept ' if result.source_mask is not None else ''}"
        f"source points within {check.max_correspondence_distance:.3g} of "
        f"{Path(args.template).name} (the inlier distance, {DEFAULT_SPACINGS:g} spacings)"
    )
    if check.verdict != "likely correct":
        print(
            f"masknet: warning: the result is {check.verdict}: {check.reason}; check it in --html",
            file=sys.stderr,
        )
    if args.viewpoint is not None and result.scene is None:
        print(
            "masknet: warning: --viewpoint was not used: it serves the scene search, and none "
            "ran (--scene on forces one)",
            file=sys.stderr,
        )


def split_weights(given: list[str], method: str) -> tuple[str | None, object | None]:
    """``--weights``, given up to twice, as (the mask network's name or file, or None; the
    learned ``method``'s network loaded from its file, or None). A file's metadata says
    which network it holds."""
    from masknet.cli._common import is_weights_file
    from masknet.models import REGISTRATION_NETWORKS
    from masknet.models.weights import read_metadata

    masks, network = [], None
    for text in given:
        held = is_weights_file(text) and next(
            (
                name
                for name, kind in REGISTRATION_NETWORKS.items()
                if kind._config_key() in read_metadata(text)
            ),
            None,
        )
        if not held:
            masks.append(text)
        elif held != method:
            raise MaskNetError(f"{text}: holds {held} weights; they need --method {held}")
        elif network is not None:
            raise MaskNetError(f"--weights: two files of {held} weights; give one")
        else:
            network = REGISTRATION_NETWORKS[held].from_file(text)
    if len(masks) > 1:
        raise MaskNetError(f"--weights: two mask networks ({', '.join(masks)}); give one")
    return (masks[0] if masks else None), network


def method_option(text: str) -> tuple[str, object]:
    """``--option NAME=VALUE``: the value read as JSON (numbers, true/false, lists), else
    as text."""
    import json

    name, sep, value = text.partition("=")
    if not sep or not name.strip().isidentifier():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        return name.strip(), json.loads(value)
    except ValueError:
        return name.strip(), value


def threshold_option(args: argparse.Namespace) -> float | None:
    """``--mask-threshold``, or ``--threshold``, its former name, with a warning on stderr."""
    if args.deprecated_threshold is None:
        return args.mask_threshold
    print(
        "masknet: warning: --threshold is deprecated; it is --mask-threshold, MaskNet's score "
        "cut-off (Open3D's threshold, the pair cut-off, is --max-correspondence-distance)",
        file=sys.stderr,
    )
    return args.deprecated_threshold
