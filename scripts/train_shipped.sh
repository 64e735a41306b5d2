#!/bin/bash
# The shipped MaskNet weights: full ModelNet40 train split, then the seen-20 model.
cd "$(dirname "$0")/.."  # the repository root
export MASKNET_DATA=../shared/data/modelnet40/modelnet40_1024_int16.npz
R=""; [ -f runs/modelnet40/checkpoint.pt ] && R=--resume
.venv/bin/masknet train --out runs/modelnet40 --epochs 14 --lr 1e-4 --lr-schedule cosine --max-minutes 80 $R
R=""; [ -f runs/seen20/checkpoint.pt ] && R=--resume
.venv/bin/masknet train --out runs/seen20 --categories seen --epochs 11 --lr 1e-4 --lr-schedule cosine --max-minutes 30 $R
