"""The ``--scans`` options of ``masknet train`` and ``masknet evaluate``: real scans as data."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from masknet.cli._common import positive_int
from masknet.errors import MaskNetError

if TYPE_CHECKING:
    from masknet.data.scans import Scan
    from masknet.data.views import ViewConfig
    from masknet.training.scan_mix import ScanMix


def names(text: str) -> list[str]:
    """A comma-separated list of scan names (file stems)."""
    out = [part.strip() for part in text.split(",") if part.strip()]
    if not out:
        raise argparse.ArgumentTypeError("expected comma-separated scan names (file stems)")
    return out


def _scans_group(p: argparse.ArgumentParser, description: str) -> argparse._ArgumentGroup:
    """The ``real scans`` group, with ``--scans``."""
    g = p.add_argument_group("real scans", description)
    g.add_argument("--scans", metavar="DIR", help="folder of .ply/.pcd/.xyz/.npy/.bin scans")
    return g


def _add_pair_options(g: argparse._ArgumentGroup, noise: float, noise_help: str) -> None:
    """How a scan pair is cut: ``--scan-points`` and ``--scan-noise`` (default ``noise``)."""
    g.add_argument(
        "--scan-points", type=positive_int, default=512, help="template points per scan pair"
    )
    g.add_argument("--scan-noise", type=float, default=noise, help=noise_help)


def add_train_options(p: argparse.ArgumentParser) -> None:
    """The ``real scans`` group of ``masknet train``."""
    g = _scans_group(
        p,
        "train MaskNet on sensor-like pairs cut from crops of your own scans (no labels "
        "needed), mixed with ModelNet40 when it is given (--data or $MASKNET_DATA)",
    )
    g.add_argument(
        "--val-scans",
        type=names,
        metavar="NAMES",
        help="scans held out whole for validation, comma-separated file stems (default: "
        "every fifth scan in name order, starting with the third)",
    )
    g.add_argument("--scan-batches", type=positive_int, default=128, help="scan batches per epoch")
    g.add_argument(
        "--modelnet-fraction",
        type=float,
        default=0.5,
        help="fraction of the ModelNet40 training shapes used per epoch beside the scans "
        "(0: scans alone)",
    )
    _add_pair_options(
        g,
        noise=0.01,
        noise_help="largest Gaussian noise on a scan pair's source, in crop radii (each pair "
        "draws its own from [0, this])",
    )


def add_evaluate_options(p: argparse.ArgumentParser) -> None:
    """The ``real scans`` group of ``masknet evaluate``."""
    g = _scans_group(p, "evaluate on sensor-like pairs cut from scans instead of ModelNet40")
    g.add_argument(
        "--scan-names", type=names, metavar="NAMES", help="only these scans (file stems)"
    )
    g.add_argument(
        "--pairs-per-scan",
        type=positive_int,
        default=50,
        help="pairs cut from each scan (default 50)",
    )
    _add_pair_options(
        g,
        noise=0.002,
        noise_help="Gaussian noise on the source, in crop radii (0.002: 0.2%% of the radius)",
    )
    g.add_argument(
        "--no-registration",
        action="store_true",
        help="masks only: skip ICP against Mask-ICP on the same pairs",
    )


def view_config(args: argparse.Namespace, noise: float, random_noise: bool) -> ViewConfig:
    """The :class:`~masknet.data.views.ViewConfig` of the options (keep ratio and angle
    come from the pair options)."""
    from masknet.data.views import ViewConfig

    try:
        return ViewConfig(
            template_points=args.scan_points,
            keep_ratio=0.7 if args.keep_ratio is None else args.keep_ratio,
            max_angle_deg=args.max_angle,
            max_translation=args.max_translation,
            noise_sigma=noise,
            random_noise=random_noise,
        )
    except ValueError as exc:
        raise MaskNetError(f"scan pairs: {exc}") from None


def read_scans(folder: str, only: list[str] | None = None) -> list[Scan]:
    """The usable scans in ``folder`` (one warning line per unusable file), optionally
    only those named."""
    from masknet.data.scans import load_scans

    scans = load_scans(folder)
    if only:
        missing = sorted(set(only) - {s.name for s in scans})
        if missing:
            raise MaskNetError(f"{folder}: no usable scan named {', '.join(missing)}")
        scans = [s for s in scans if s.name in only]
    return scans


def scan_mix(args: argparse.Namespace, **settings) -> ScanMix:
    """The scans of ``--scans`` as a task's :class:`~masknet.training.scan_mix.ScanMix`
    (whole scans held out for validation), with ``settings`` of the task's own."""
    from masknet.data.scans import split_scans
    from masknet.training.scan_mix import ScanMix

    if not 0 <= args.modelnet_fraction <= 1:
        raise MaskNetError(f"--modelnet-fraction must be in [0, 1], got {args.modelnet_fraction}")
    if args.scan_noise < 0:
        raise MaskNetError(f"--scan-noise must be >= 0, got {args.scan_noise}")
    train, val = split_scans(read_scans(args.scans), args.val_scans)
    print(
        f"scans: {len(train)} for training, {len(val)} held out "
        f"({', '.join(s.name for s in val) or 'none'})"
    )
    return ScanMix(
        scans=train,
        val_scans=val,
        view=view_config(args, args.scan_noise, random_noise=True),
        scan_batches=args.scan_batches,
        modelnet_fraction=args.modelnet_fraction,
        **settings,
    )
