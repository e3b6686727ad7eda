#!/bin/sh
# Make the default model (guardrail_core/models/default) again: four simulated drives of the
# paper's profile scanner with cameras and eight of a multi-beam scanner (a Velodyne HDL-64E as
# on the KITTI car, one frame every 30 m, no images), fast mode. About 8 minutes on 2 cores.
# Usage: sh docs/train_default_model.sh [WORK_DIR]   (run from the repository root)
set -e
work=${1:-default_model_work}
mkdir -p "$work"
for seed in 101 102 103 104; do
    .venv/bin/guardrail simulate "$work/train_$seed" --seed $seed --length 150 --quiet --overwrite
done
for seed in 501 502 503 504 505 506 507 508; do
    .venv/bin/guardrail simulate "$work/mb_$seed" --seed $seed --length 300 --scanner multibeam \
        --frame-every 30 --image-every 10000 --quiet --overwrite
done
.venv/bin/guardrail train "$work"/train_10? "$work"/mb_50? --out "$work/model" --overwrite
echo "copy $work/model/model.json and weights.npz into guardrail_core/models/default/"
