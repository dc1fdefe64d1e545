#!/usr/bin/env bash
# Regenerates every file of the hall dataset: the world from make_world.py, the test log from
# poses.csv, the mapping run from make_mapping_poses.py, and the map from the mapping run only.
# Run from the repository root:  bash datasets/hall/regenerate.sh   (or: make hall)
set -euo pipefail
cd "$(dirname "$0")"
BIN=../../.venv/bin
$BIN/python make_world.py
# The 10 test scans, localized by `make demo` from the paper's initial errors.
$BIN/segloc simulate world.json --poses poses.csv --out . --readings 1024 --noise-cm 1.2 --seed 2000 --init-errors paper --force
# The mapping run: its own path, noise and seed; /odom holds its wheel odometry, drifting.
$BIN/python make_mapping_poses.py
$BIN/segloc simulate world.json --poses mapping_poses.csv --out mapping --readings 1024 --noise-cm 1.5 --seed 1000 --odometry drift --force
$BIN/segloc map build mapping/log.mcap --survey mapping/survey.csv --out map.json --force
