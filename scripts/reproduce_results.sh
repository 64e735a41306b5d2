#!/bin/bash
# Every figure in docs/RESULTS.md (the full benchmark takes about 4.5 hours on 2 CPU cores; it resumes with --resume).
# Needs the ModelNet40 data (MASKNET_DATA) and, for the scans experiment, ../shared/data/scans.
set -e
cd "$(dirname "$0")/.."
export MASKNET_DATA=${MASKNET_DATA:-../shared/data/modelnet40/modelnet40_1024_int16.npz}
M=.venv/bin/masknet
$M evaluate --pairs 1000 --seed 0 --precision fp32 -o docs/results/eval_modelnet40.json
$M evaluate --pairs 1000 --seed 0 --precision bf16 -o docs/results/eval_modelnet40_bf16.json
$M evaluate --pairs 1000 --seed 0 --weights modelnet40_seen20 --categories unseen --precision fp32 -o docs/results/eval_seen20_unseen.json
$M evaluate --pairs 1000 --seed 0 --weights modelnet40_seen20 --categories seen --precision fp32 -o docs/results/eval_seen20_seen.json
.venv/bin/python -m masknet.evaluation.timing --threads 2 --repeats 100 --data "$MASKNET_DATA" --scaling --training --json docs/results/timing.json
$M benchmark all --threads 2 -o docs/results/full --results docs/results/full/RESULTS.md
.venv/bin/python scripts/rounds_on_real_pair.py --scans ../shared/data/scans --out docs/results/rounds_3dmatch.json
.venv/bin/python scripts/mask_precision_ceiling.py --out docs/results/mask_precision_ceiling.json
