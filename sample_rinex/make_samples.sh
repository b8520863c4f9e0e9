#!/bin/sh
# Regenerates the sample data sets of this folder (same seed, same bytes).
# Run from the repository root: sh sample_rinex/make_samples.sh
set -e
SIM="python -m gnss_cli.cli.simulate"
# static receiver, 1 h at 30 s, GPS + Galileo, every error source (outliers: none chosen)
$SIM --trajectory static --start 2024-03-01T00:00:00 --duration 3600 --interval 30 \
     --systems G,E --seed 7 --errors all --out-dir sample_rinex/static --quiet
