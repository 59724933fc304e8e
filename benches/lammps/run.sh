#!/bin/sh
# Throughput of grainforce's DEM against LAMMPS (granular package) on the
# same `box` systems. Not part of the test suite.
#
#   benches/lammps/run.sh [--large]
#
# Installs the Debian package `lammps` when `lmp` is missing, then runs
# examples/dem_throughput.rs, which prepares the systems, times grainforce,
# writes the LAMMPS inputs (pair gran/hooke/history, fix wall/gran,
# nve/sphere) to target/dem_bench/ and runs them with `lmp` on one core.
set -eu
cd "$(dirname "$0")/../.."
if ! command -v lmp >/dev/null 2>&1; then
    echo "lmp not found: installing the Debian package lammps" >&2
    if [ "$(id -u)" -eq 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update
    $SUDO apt-get install -y lammps
fi
export OMP_NUM_THREADS=1
cargo run --release --example dem_throughput -- "$@"
