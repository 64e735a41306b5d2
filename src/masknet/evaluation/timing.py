"""Speed of MaskNet's inference variants, measured in one run so ratios are fair.

    python -m masknet.evaluation.timing --threads 2 --repeats 100 --data $DATA --json out.json

Variants (each a function ``(template (B, N, 3), source (B, M, 3)) -> scores (B, N)``):

* ``reference``: the paper's formulation, :class:`~masknet.models.reference.PaperMaskNet`
  (Conv1d, concatenated global feature), fp32: the baseline of every ratio;
* ``split head, fp32``: :meth:`MaskNet.forward` (first head layer split);
* ``fused, fp32`` and ``fused, bf16``: :class:`~masknet.models.FusedMaskNet` (split head,
  BatchNorm folded, channels-last GEMMs), the library's inference path;
* ``dynamic int8``: ``torch.ao.quantization.quantize_dynamic`` on the Linear layers;
* ``torch.compile``: the split-head forward compiled (inductor);
* ``onnxruntime``: the split-head forward exported to ONNX, run by onnxruntime
  (skipped, with a note, when onnx/onnxruntime are not installed).

Each variant gets warm-up calls, then the median of ``repeats`` timed calls: at batch 1
(latency) and batch 32 (throughput). With ``--data``, each variant's top-k mask
agreement with fp32 and its change in top-k precision are measured on
``--agreement-pairs`` seeded ModelNet40 test pairs; ``--scaling`` times the default
path for N from 512 to 16,384 template points.
"""

from __future__ import annotations

import argparse
import copy
import json
import platform
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from masknet.data import PairConfig, bundled_sample_path, load_modelnet40, make_test_pairs
from masknet.io import write_text_atomic
from masknet.metrics import mask_metrics
from masknet.models import MaskNet, select_mask
from masknet.models.reference import PaperMaskNet
from masknet.runtime import default_precision

__all__ = [
    "chunked_large_template",
    "masknet_variants",
    "median_ms",
    "n_scaling",
    "time_variants",
    "variant_agreement",
]

Variant = Callable[[Tensor, Tensor], Tensor]
REFERENCE = "reference (Conv1d, concat, fp32)"


def median_ms(fn: Callable[[], object], repeats: int = 50, warmup: int = 5) -> float:
    """Median wall time of ``fn()`` in milliseconds, after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


class _Forward(nn.Module):
    """MaskNet's split-head forward as a plain two-input module (for export and compile)."""

    def __init__(self, model: MaskNet):
        super().__init__()
        self.model = model

    def forward(self, template: Tensor, source: Tensor) -> Tensor:
        return self.model(template, source)


def _onnx_variant(model: MaskNet, threads: int) -> Variant | str:
    try:
        import onnxruntime as ort
    except ImportError:
        return "skipped: pip install onnx onnxruntime to measure it"
    path = Path(tempfile.mkdtemp()) / "masknet.onnx"
    torch.onnx.export(
        _Forward(model).eval(),
        (torch.rand(1, 1024, 3), torch.rand(1, 717, 3)),
        str(path),
        input_names=["template", "source"],
        output_names=["scores"],
        dynamic_axes={"template": {0: "b", 1: "n"}, "source": {0: "b", 1: "m"}},
        dynamo=False,
    )
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])

    def run(t: Tensor, s: Tensor) -> Tensor:
        feed = {"template": t.numpy(), "source": s.numpy()}
        return torch.from_numpy(session.run(None, feed)[0])

    return run


def masknet_variants(model: MaskNet, extended: bool = True) -> dict[str, Variant | str]:
    """name -> scoring function, or a string saying why the variant was skipped."""
    model = model.eval()
    reference = PaperMaskNet(model).eval()
    variants: dict[str, Variant | str] = {
        REFERENCE: reference,
        "split head, fp32": model,
        "fused, fp32": lambda t, s: model.fused("fp32")(t, s),
        "fused, bf16": lambda t, s: model.fused("bf16")(t, s),
    }
    if extended:
        quantized = torch.ao.quantization.quantize_dynamic(
            copy.deepcopy(model), {nn.Linear}, dtype=torch.qint8
        )
        variants["dynamic int8 (Linear)"] = quantized
        variants["torch.compile (split head, fp32)"] = torch.compile(_Forward(model).eval())
        variants["onnxruntime (split head, fp32)"] = _onnx_variant(model, torch.get_num_threads())
    return variants


def time_variants(
    variants: dict[str, Variant | str], batch: int, repeats: int, seed: int = 0
) -> dict[str, dict]:
    """ms per call of each variant on seeded sample pairs (N = 1024, M = 717), and the
    speed-up against the reference."""
    points = load_modelnet40(bundled_sample_path(), "test").points
    pairs = make_test_pairs(points, batch, PairConfig(), seed)
    t, s = pairs.template, pairs.source
    results: dict[str, dict] = {}
    with torch.inference_mode():
        for name, fn in variants.items():
            if isinstance(fn, str):
                results[name] = {"note": fn}
                continue
            ms = median_ms(lambda fn=fn: fn(t, s), repeats=repeats)
            results[name] = {"ms": ms, "pairs_per_s": 1000 * batch / ms}
    base = results[REFERENCE]["ms"]
    for row in results.values():
        if "ms" in row:
            row["speedup"] = base / row["ms"]
    return results


def variant_agreement(
    variants: dict[str, Variant | str], points: np.ndarray, num_pairs: int = 1000, seed: int = 0
) -> dict[str, dict]:
    """Top-k (k = M) mask agreement of each variant with fp32 (the split head), and its
    change in mean top-k precision, on seeded test pairs (default protocol)."""
    pairs = make_test_pairs(points, num_pairs, PairConfig(), seed)
    k = pairs.source.shape[1]

    def masks(fn: Variant) -> Tensor:
        out = []
        with torch.inference_mode():
            for i in range(0, num_pairs, 50):
                out.append(fn(pairs.template[i : i + 50], pairs.source[i : i + 50]).float())
        return select_mask(torch.cat(out), k=k)

    fp32 = masks(variants["split head, fp32"])
    base = mask_metrics(fp32, pairs.mask).precision.mean().item()
    results = {}
    for name, fn in variants.items():
        if isinstance(fn, str):
            continue
        mask = masks(fn)
        precision = mask_metrics(mask, pairs.mask).precision.mean().item()
        results[name] = {
            "point_agreement": (mask == fp32).float().mean().item(),
            "identical_masks": (mask == fp32).all(1).float().mean().item(),
            "precision": precision,
            "precision_change": precision - base,
        }
    return results


def n_scaling(model: MaskNet, sizes: list[int], repeats: int = 10) -> list[dict]:
    """Batch-1 latency of the default path and of the reference as the template grows
    (source = 70% of the template, sampled from a sphere)."""
    precision = default_precision("cpu")
    reference = PaperMaskNet(model).eval()
    rows = []
    gen = torch.Generator().manual_seed(0)
    with torch.inference_mode():
        for n in sizes:
            t = torch.randn(1, n, 3, generator=gen)
            t = t / t.norm(dim=-1, keepdim=True)
            s = t[:, : int(0.7 * n)] + 0.1
            fast = median_ms(
                lambda t=t, s=s: model.fused(precision)(t, s, chunk_size=8192), repeats
            )
            ref = median_ms(lambda t=t, s=s: reference(t, s), max(3, repeats // 3), warmup=1)
            rows.append(
                {"n": n, "m": s.shape[1], f"fused_{precision}_ms": fast, "reference_ms": ref,
                 "speedup": ref / fast}
            )  # fmt: skip
    return rows


def chunked_large_template(model: MaskNet, n: int = 100_000, chunk_size: int = 8192) -> dict:
    """A template of ``n`` points scored in chunks and in one piece: the largest score
    difference, the time of each, and the process's peak memory after each (chunked
    first, since the peak only grows)."""
    import resource

    gen = torch.Generator().manual_seed(1)
    t = torch.randn(1, n, 3, generator=gen)
    t = t / t.norm(dim=-1, keepdim=True)
    s = t[:, : int(0.7 * n) : 100] + 0.1  # a 700-point partial source
    fused = model.fused("fp32")

    def peak_mb() -> float:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    with torch.inference_mode():
        start = time.perf_counter()
        chunked = fused(t, s, chunk_size=chunk_size)
        chunked_s, chunked_mb = time.perf_counter() - start, peak_mb()
        start = time.perf_counter()
        whole = fused(t, s, chunk_size=None)
        whole_s, whole_mb = time.perf_counter() - start, peak_mb()
    return {
        "n": n,
        "chunk_size": chunk_size,
        "max_abs_difference": float((chunked - whole).abs().max()),
        "chunked_s": chunked_s,
        "unchunked_s": whole_s,
        "peak_rss_mb_after_chunked": chunked_mb,
        "peak_rss_mb_after_unchunked": whole_mb,
    }


def training_step_ms(batch: int = 32, repeats: int = 5) -> dict[str, float]:
    """ms per training step (forward, backward, Adam) at batch 32, N = 1024: the paper's
    concatenated head in fp32 against the split head with bf16 autocast (where native)."""
    points = load_modelnet40(bundled_sample_path(), "test").points
    pairs = make_test_pairs(points, batch, PairConfig(), 0)
    t, s, target = pairs.template, pairs.source, pairs.mask.float()
    torch.manual_seed(0)
    model = MaskNet().train()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
    bf16 = default_precision("cpu") == "bf16"

    def step(forward: Callable[[Tensor, Tensor], Tensor], autocast: bool) -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
            loss = nn.functional.mse_loss(forward(t, s).float(), target)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    rows = {
        "concat head, fp32": median_ms(
            lambda: step(model.forward_reference, False), repeats, warmup=1
        ),
        "split head, fp32": median_ms(lambda: step(model.forward, False), repeats, warmup=1),
    }
    if bf16:
        rows["split head, bf16 autocast"] = median_ms(
            lambda: step(model.forward, True), repeats, warmup=1
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--json")
    parser.add_argument("--data", help="ModelNet40 data: also measure mask agreement")
    parser.add_argument("--agreement-pairs", type=int, default=1000)
    parser.add_argument("--scaling", action="store_true", help="also time N = 512 ... 16,384")
    parser.add_argument("--basic", action="store_true", help="skip int8, compile and ONNX")
    parser.add_argument("--training", action="store_true", help="also time a training step")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    model = MaskNet.pretrained()
    variants = masknet_variants(model, extended=not args.basic)
    result: dict = {
        "threads": torch.get_num_threads(),
        "machine": f"{platform.machine()}, torch {torch.__version__}",
        "n": 1024,
        "m": 717,
    }
    for batch in (1, 32):
        rows = time_variants(
            variants, batch, args.repeats if batch == 1 else max(5, args.repeats // 5)
        )
        result[f"batch_{batch}"] = rows
        print(f"batch {batch}, N=1024, M=717, {result['threads']} threads")
        for name, row in rows.items():
            if "ms" in row:
                print(
                    f"  {name:36s}{row['ms']:9.2f} ms {row['speedup']:6.2f}x {row['pairs_per_s']:8.0f} pairs/s"
                )
            else:
                print(f"  {name:36s} {row['note']}")
    if args.data:
        test = load_modelnet40(args.data, "test").points
        result["agreement"] = variant_agreement(variants, test, args.agreement_pairs)
        result["agreement_pairs"] = args.agreement_pairs
        for name, row in result["agreement"].items():
            print(
                f"  {name:36s} agreement {row['point_agreement']:.4f}, precision change {row['precision_change']:+.4f}"
            )
    if args.scaling:
        result["scaling"] = n_scaling(model, [512, 1024, 2048, 4096, 8192, 16384])
        for row in result["scaling"]:
            print(
                "  "
                + ", ".join(
                    f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()
                )
            )
    if args.training:
        result["training_step_ms_batch32"] = training_step_ms()
        print("  training step, batch 32:", result["training_step_ms_batch32"])
    if args.scaling:
        result["chunked_100k"] = chunked_large_template(model)
        print("  100k-point template:", result["chunked_100k"])
    if args.json:
        write_text_atomic(args.json, json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
