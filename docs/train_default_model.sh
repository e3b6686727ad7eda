#!/bin/sh
# Make a default model (guardrail_core/models/default): thirteen simulated drives of the
# paper's profile scanner with cameras (nine of 150 m, four of 300 m; the 300 m town streets
# with young trees and low hedges close behind half their pipe railings, one 150 m street at
# night) and fourteen of multi-beam scanners (one frame every 30 m, no images: twelve of a
# Velodyne HDL-64E as on the KITTI car, four of those on roads with W-beam and thrie-beam
# guardrails only, one of a Pandar64 and one of an OS1-128), with motorway medians and cars in
# the lanes beside the car; fast mode. The streets have green roadsides (embankments, ditches,
# hedges behind the rails, shrubs, tall grass); on the 150 m and the multi-beam drives a third
# of the guardrail runs are 40-120 m long (--long-runs 0.35); some drives of each scanner are
# noisier and sparser than the scanner's defaults and calibrated differently (range noise,
# dropouts, intensity gain), as real deliveries are, and the segment head leaves the
# intensities unread (each scanner calibrates them otherwise). About 80 minutes on 2 cores.
# The shipped model was made by this recipe as it stood on 2026-11-27 (profile and HDL-64E
# drives without medians, traffic, young trees or night); this version's model of 2026-12-07
# (one seed) found 86.5 % of KITTI 01/280's rail against 75.0 %, but guardrail F on the
# accuracy benchmark's profile streets 10001-10004 fell to 0.980 from 0.987, and it was not
# shipped: a model ships when it holds on both, over several seeds.
# Check a model before copying it, on the labelled real frames and the simulated streets:
#   .venv/bin/python benchmarks/real_frames.py --model WORK_DIR/model
#   .venv/bin/python benchmarks/kitti_vegetation.py --model WORK_DIR/model
#   .venv/bin/python benchmarks/accuracy.py --model WORK_DIR/model
#   and tests/test_kitti_end_to_end.py with it in guardrail_core/models/default
# Usage: sh docs/train_default_model.sh [WORK_DIR]   (run from the repository root)
set -e
work=${1:-default_model_work}
mkdir -p "$work"
: > "$work/simulate.txt"
simulate() {  # simulate DRIVE ARGS...: simulate and note the command for model.json
    name=$1
    shift
    .venv/bin/guardrail simulate "$work/$name" "$@" --quiet --overwrite
    echo "$name guardrail simulate $name $*" >> "$work/simulate.txt"
}
simulate train_101 --seed 101 --length 150 --long-runs 0.35
simulate train_102 --seed 102 --length 150 --long-runs 0.35
simulate train_103 --seed 103 --length 150 --long-runs 0.35 --range-noise 0.012 --dropout 0.08 --intensity-gain 0.6
simulate train_104 --seed 104 --length 150 --long-runs 0.35 --range-noise 0.008 --dropout 0.04 --intensity-gain 1.5
# More profile-scanner streets with cameras: with four, the crop classifier and the segment head
# had seen too few guardrails of each design, paint and background, and the multi-beam drives'
# segments outnumbered theirs five to one.
for seed in 105 106 107 108; do
    simulate train_$seed --seed $seed --length 150 --long-runs 0.35
done
# Town streets: young trees on stakes and low hedges close behind half the pipe railings; one
# of them at night, lit by the vehicle's lamps.
for seed in 111 112 113 114; do
    simulate street_$seed --seed $seed --length 300 --young-trees 0.5
done
simulate street_115 --seed 115 --length 150 --long-runs 0.35 --young-trees 0.5 --night
# Multi-beam streets hold what real ones do: motorway medians (two beams back to back, a hedge
# between) and cars in the lanes beside the car; two of them are scanned by other sensors.
mb="--length 300 --long-runs 0.35 --scanner multibeam --frame-every 30 --image-every 10000 --medians 0.6 --traffic 0.5"
for seed in 501 502 503 504; do
    simulate mb_$seed --seed $seed $mb
done
simulate mb_505 --seed 505 $mb --range-noise 0.03 --dropout 0.1 --intensity-gain 0.5
simulate mb_506 --seed 506 $mb --range-noise 0.04 --dropout 0.05 --intensity-gain 1.4
simulate mb_507 --seed 507 $mb --range-noise 0.03 --dropout 0.15 --intensity-gain 0.7
simulate mb_508 --seed 508 $mb --range-noise 0.025 --dropout 0.08 --intensity-gain 2.0
simulate mb_509 --seed 509 $mb --lidar pandar64
simulate mb_510 --seed 510 $mb --lidar os1-128 --range-noise 0.02
# Roads like the KITTI car's: W-beam and thrie-beam guardrails only.
beams="--designs beam_w,beam_thrie"
simulate mbb_511 --seed 511 $mb $beams
simulate mbb_512 --seed 512 $mb $beams
simulate mbb_513 --seed 513 $mb $beams --range-noise 0.03 --dropout 0.1 --intensity-gain 0.6
simulate mbb_514 --seed 514 $mb $beams --range-noise 0.03 --dropout 0.08 --intensity-gain 1.6
.venv/bin/guardrail train "$work"/train_10? "$work"/street_11? "$work"/mb_5?? "$work"/mbb_51? --out "$work/model" \
    --ignore-features intensity_mean,intensity_std --overwrite
# Record in model.json how each training drive was simulated.
.venv/bin/python - "$work" <<'EOF'
import json, sys
from pathlib import Path

work = Path(sys.argv[1])
commands = dict(line.split(" ", 1) for line in (work / "simulate.txt").read_text().splitlines())
path = work / "model" / "model.json"
model = json.loads(path.read_text())
for drive in model["trained_on"]["drives"]:
    drive["drive"] = Path(drive["drive"]).name
    drive["simulate"] = commands[drive["drive"]]
path.write_text(json.dumps(model, indent=2) + "\n")
EOF
echo "copy $work/model/model.json and weights.npz into guardrail_core/models/default/"
