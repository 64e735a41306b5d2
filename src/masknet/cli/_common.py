"""What several commands share: argument validators, option groups, model loading, and
writing outputs all-or-nothing."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from masknet._extras import PICTURES, require
from masknet.errors import MaskNetError

if TYPE_CHECKING:
    import numpy as np

    from masknet.data import PairConfig
    from masknet.models import MaskNet


def int_at_least(low: int, name: str):
    """An argparse type: an integer >= ``low``. argparse calls it ``name`` when the text is
    no integer ("invalid positive_int value: 'x'")."""

    def parse(text: str) -> int:
        value = int(text)
        if value < low:
            raise argparse.ArgumentTypeError(f"must be at least {low}, got {value}")
        return value

    parse.__name__ = name
    return parse


positive_int = int_at_least(1, "positive_int")
at_least_three = int_at_least(3, "at_least_three")  # points enough for a rotation


def seed(text: str) -> int:
    """argparse type: an integer >= 0."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be non-negative, got {value}")
    return value


def finite_float(text: str) -> float:
    """argparse type: a float that is neither NaN nor infinite."""
    value = float(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


# What ``masknet`` exits with: one table, printed by ``masknet register --help`` and the
# README (a test compares them).
EXIT_OK, EXIT_REFUSED, EXIT_LIKELY_WRONG, EXIT_SOME_FAILED, EXIT_INTERRUPTED = 0, 2, 3, 4, 130
EXIT_CODES = {
    EXIT_OK: "done; register: the verdict is likely correct or uncertain (uncertain is "
    "printed as a warning)",
    1: "an unexpected error, with a traceback: a bug, please report it",
    EXIT_REFUSED: "refused: a bad file, option or value, said in one line; nothing written",
    EXIT_LIKELY_WRONG: "register: the outputs are written, but the verdict is likely wrong; "
    "register-many: some results are likely wrong (--exit-zero gives 0 instead)",
    EXIT_SOME_FAILED: "register-many: some pairs failed (a bad file, a refusal); the others "
    "are written and summary.csv gives each error (--exit-zero gives 0 instead)",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C); no output half-written, and the line says what "
    "is already written",
}


def exit_codes_text() -> str:
    """The exit-status table as ``--help`` prints it."""
    return "exit status:\n" + "\n".join(f"  {code:>3}  {text}" for code, text in EXIT_CODES.items())


class StartFile(NamedTuple):
    """``--init FILE``: the file, an input no output may overwrite (a run refining an
    earlier ``<stem>_transform.txt``), and the (4, 4) source -> template matrix it holds."""

    path: str
    matrix: np.ndarray


def init_option(text: str) -> str | StartFile:
    """``--init``: ``centroid``, ``identity``, or a file holding a 4x4 source -> template
    matrix to start from (Open3D's ``init``): text (``#`` comments, as the
    ``<stem>_transform.txt`` that ``masknet register`` writes) or ``.npy``. A command
    takes it apart with :func:`start_files`."""
    if text in ("centroid", "identity"):
        return text
    import numpy as np

    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(
            f"{text!r} is neither centroid, identity nor a file holding a 4x4 matrix"
        )
    try:
        if path.suffix.lower() == ".npy":
            matrix = np.load(path, allow_pickle=False)
        else:
            matrix = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise argparse.ArgumentTypeError(f"{text}: not a 4x4 matrix ({exc})") from None
    if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
        raise argparse.ArgumentTypeError(
            f"{text}: expected a finite 4x4 matrix, got shape {matrix.shape}"
        )
    return StartFile(text, matrix.astype(np.float64))


def start_files(args: argparse.Namespace) -> list[str]:
    """The file of ``--init`` (none for ``centroid`` and ``identity``), for the output
    rule; ``args.init`` is left as ``register``'s ``init`` takes it, a name or the matrix."""
    if not isinstance(args.init, StartFile):
        return []
    path, args.init = args.init
    return [path]


def json_object(text: str) -> dict:
    """argparse type: a JSON object (dict)."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"not valid JSON ({exc.msg}): {text}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"must be a JSON object, got {text}")
    return value


def add_pair_options(p: argparse.ArgumentParser) -> None:
    """The ``pair generation`` group: how ModelNet40 pairs are made (see :func:`pair_config`)."""
    g = p.add_argument_group("pair generation")
    g.add_argument(
        "--protocol",
        choices=["paper", "official"],
        default="paper",
        help="paper: random viewpoint, angle in [0, max-angle], translation in the cube; "
        "official: the authors' code (768 points, twist <= 0.8)",
    )
    g.add_argument(
        "--keep-ratio",
        type=float,
        default=None,
        help="fraction of template points the source keeps (default 0.7; "
        "1.0 when training pointnetlk, which trains on full clouds)",
    )
    g.add_argument(
        "--max-angle", type=float, default=45.0, help="maximum rotation, degrees (default 45)"
    )
    g.add_argument(
        "--max-translation",
        type=float,
        default=1.0,
        help="translation range per axis (default 1.0)",
    )
    g.add_argument(
        "--noise",
        type=float,
        default=0.0,
        help="Gaussian noise sigma on the source (clipped at 0.05)",
    )
    g.add_argument(
        "--outliers",
        type=float,
        default=None,
        help="fraction of uniform outliers added (default 0; 0.1 when training denoise)",
    )
    g.add_argument(
        "--outlier-target",
        choices=["source", "template"],
        default="source",
        help="which cloud gets the --outliers (default source)",
    )
    g.add_argument(
        "--categories",
        choices=["all", "seen", "unseen"],
        default="all",
        help="all 40, the first 20 (seen) or the last 20 (unseen) categories, alphabetical",
    )


def pair_config(
    args: argparse.Namespace, default_keep_ratio: float = 0.7, default_outliers: float = 0.0
) -> PairConfig:
    """The :class:`~masknet.data.PairConfig` of the ``pair generation`` options."""
    from masknet.data import PairConfig

    keep = default_keep_ratio if args.keep_ratio is None else args.keep_ratio
    outliers = default_outliers if args.outliers is None else args.outliers
    try:
        return PairConfig(
            keep_ratio=keep,
            max_angle_deg=args.max_angle,
            max_translation=args.max_translation,
            noise_sigma=args.noise,
            outlier_ratio=outliers,
            outlier_target=args.outlier_target,
            protocol=args.protocol,
        )
    except ValueError as exc:
        raise MaskNetError(str(exc)) from None


def add_cloud_arguments(p: argparse.ArgumentParser, source_help: str) -> None:
    """The positional ``template`` and ``source`` files of ``mask`` and ``register``."""
    p.add_argument("template", help="full cloud: .ply .pcd .xyz .txt .csv .npy .bin")
    p.add_argument("source", help=source_help)


def add_file_options(p: argparse.ArgumentParser, html: bool = True) -> None:
    """Options of every command that reads clouds from files (and optionally shows them)."""
    p.add_argument(
        "--drop-nonfinite",
        action="store_true",
        help="drop NaN/inf rows instead of failing (mask files, where a command writes them, "
        "still have a line per input row, 0 there)",
    )
    if html:
        p.add_argument(
            "--html",
            metavar="PATH",
            help="also write an interactive 3D view (offline HTML) here, and a PNG beside it",
        )


class _OldSpelling(argparse.Action):
    """An option's old spelling, kept for one version: it sets what the new spelling sets
    (appending where the new one appends) and says so in one line on stderr."""

    def __init__(self, option_strings, dest, new: str, append: bool = False, **kwargs) -> None:
        super().__init__(option_strings, dest, **kwargs)
        self.new, self.append = new, append

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        import sys

        print(
            f"masknet: warning: {option_string} is deprecated and goes in the next version; "
            f"use {self.new}",
            file=sys.stderr,
        )
        if self.append:
            values = [*(getattr(namespace, self.dest, None) or []), values]
        setattr(namespace, self.dest, values)


def add_old_spelling(
    p: argparse.ArgumentParser | argparse._ArgumentGroup,
    old: str,
    new: str,
    dest: str,
    append: bool = False,
    **kwargs,
) -> None:
    """Accept ``old`` for one version as ``new`` (stored in ``dest``), with a one-line
    deprecation warning; hidden from ``--help``."""
    p.add_argument(
        old,
        dest=dest,
        action=_OldSpelling,
        new=new,
        append=append,
        help=argparse.SUPPRESS,
        **kwargs,
    )


def add_output_option(
    p: argparse.ArgumentParser, help: str, old: str | None = None, **kwargs
) -> None:
    """``-o/--output``, every command's one spelling of where its results go; ``old``, an
    earlier spelling of the command's, still works for one version."""
    if old is None:
        p.add_argument("-o", "--output", help=help, **kwargs)
        return
    # argparse counts a required option as given by its own flags only: the two spellings
    # form a required group (its message names only -o/--output, the old one is hidden).
    required = kwargs.pop("required", False)
    group = p.add_mutually_exclusive_group(required=required) if required else p
    group.add_argument("-o", "--output", help=help, **kwargs)
    kwargs.pop("default", None)
    add_old_spelling(group, old, "-o/--output", "output", **kwargs)


def add_model_options(
    p: argparse.ArgumentParser,
    default_weights: str | None = "modelnet40",
    kind: str = "MaskNet",
    default_text: str | None = None,
    several: bool = False,
) -> None:
    """The ``model`` group: which weights (``--weights NAME_OR_FILE``: shipped weights by
    name, or a .safetensors file), and the networks' precision. ``default_weights`` None:
    each network's own shipped default (``default_text`` says which). ``several``:
    ``--weights`` may be given more than once (a list), for commands that load several
    networks."""
    g = p.add_argument_group("model")
    g.add_argument(
        "--weights",
        metavar="NAME_OR_FILE",
        default=[] if several else default_weights,
        action="append" if several else "store",
        help=f"the name of shipped {kind} weights, or a .safetensors file from masknet train "
        f"(default {default_text or default_weights})",
    )
    add_old_spelling(g, "--pretrained", "--weights NAME", "weights", append=several)
    g.add_argument(
        "--precision",
        choices=["auto", "fp32", "bf16"],
        default="auto",
        help="the networks' precision: auto, bf16 where the CPU/GPU runs it natively (mask "
        "agreement 99.7%% with fp32), else fp32",
    )
    add_old_spelling(
        g, "--inference-precision", "--precision", "precision", choices=["auto", "fp32", "bf16"]
    )


def is_weights_file(text: str) -> bool:
    """Whether ``--weights`` names a file (a .safetensors path, a path with a folder, or an
    existing file) rather than shipped weights by name."""
    path = Path(text)
    return path.suffix.lower() == ".safetensors" or len(path.parts) > 1 or path.is_file()


def load_weights(kind, text: str):
    """``kind`` (a network class with ``from_file`` and ``pretrained``) from ``--weights``
    ``text``: a file, or shipped weights by name."""
    return kind.from_file(text) if is_weights_file(text) else kind.pretrained(text)


def load_model(args: argparse.Namespace, two_sided: bool = False) -> MaskNet:
    """The MaskNet of the ``model`` options; resolves ``--precision auto``.

    ``two_sided``: shipped names are two-sided MaskNets (``masknet2_<name>``), and a
    ``--weights`` file may hold either kind (its metadata says which). A file of
    CrossMaskNet weights (``masknet train --model crossmasknet``), or shipped ones named
    ``crossmasknet_<name>``, give a CrossMaskNet, which answers MaskNet's calls.
    ``--weights`` unset: the kind's own shipped default.
    """

    from masknet.models import CrossMaskNet, MaskNet
    from masknet.models.two_sided import TwoSidedMaskNet
    from masknet.models.weights import read_metadata
    from masknet.runtime import default_precision

    if args.precision == "auto":
        args.precision = default_precision("cpu")
    kind = TwoSidedMaskNet if two_sided else MaskNet
    if not args.weights:
        return kind.pretrained()
    if args.weights.startswith(CrossMaskNet.weights_prefix) and not is_weights_file(args.weights):
        return CrossMaskNet.pretrained(args.weights.removeprefix(CrossMaskNet.weights_prefix))
    if is_weights_file(args.weights):
        held = read_metadata(args.weights)
        if CrossMaskNet._config_key() in held:
            kind = CrossMaskNet  # a template mask with MaskNet's calls
        elif two_sided and TwoSidedMaskNet._config_key() not in held:
            kind = MaskNet  # a paper MaskNet file: it masks the template only
    return load_weights(kind, args.weights)


PROGRESS_AFTER_S = 2.0  # steps that take longer say so on stderr


@contextlib.contextmanager
def progress(label: str, after: float | None = None) -> Iterator[None]:
    """Print ``masknet: <label> ...`` to stderr once a step has run ``after`` seconds
    (default :data:`PROGRESS_AFTER_S`), and its time when it ends; quick steps print
    nothing."""
    import sys
    import threading
    import time

    start = time.perf_counter()
    shown = threading.Event()

    def announce() -> None:
        shown.set()
        print(f"masknet: {label} ...", file=sys.stderr, flush=True)

    timer = threading.Timer(PROGRESS_AFTER_S if after is None else after, announce)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
    # Only a step that ended is "done": an interrupt or an error says so itself.
    if shown.is_set():
        elapsed = time.perf_counter() - start
        print(f"masknet: {label}: done in {elapsed:.1f} s", file=sys.stderr, flush=True)


def check_html(path: str | None) -> list[Path]:
    """The viewer's path (and its PNG twin) for :func:`check_outputs`; it must end in .html."""
    if path is None:
        return []
    html = Path(path)
    if html.suffix.lower() != ".html":
        raise MaskNetError(f"{html}: the viewer is an .html file; give a name ending in .html")
    require(*PICTURES)  # for the PNG; refused now, not after the computing
    return [html, html.with_suffix(".png")]
