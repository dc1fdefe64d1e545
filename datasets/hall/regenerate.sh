#!/usr/bin/env bash
# Regenerates every file of the hall dataset from world.json's source and poses.csv.
# Run from the repository root:  bash datasets/hall/regenerate.sh   (or: make hall)
set -euo pipefail
cd "$(dirname "$0")"
BIN=../../.venv/bin
$BIN/python make_world.py
$BIN/segloc simulate world.json --poses poses.csv --out . --readings 1024 --noise-cm 1.2 --seed 2000 --init-errors paper
$BIN/segloc map build log.mcap --survey survey.csv --out map.json
