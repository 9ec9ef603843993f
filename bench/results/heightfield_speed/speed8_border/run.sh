#!/bin/sh
# With border2.patch applied: same_bits (run first, commented out on the rerun), then the
# interleaved CPU profile on both scenes (main = both new switches 0)
cd "$(dirname "$0")/../../../.."
D=bench/results/heightfield_speed/speed8_border
P=".venv/bin/python"
OFF="-DHF_NARROW_FAST=0 -DHF_SPREAD16_FAST=0"
# PYOPENCL_CTX=0 $P $D/same_bits.py "-DHF_OUTSIDE_FAST=0 -DHF_STRADDLE_FAST=0 $OFF" "" "-DHF_EARLY_EXIT=0 -DHF_OUTSIDE_FAST=0 -DHF_STRADDLE_FAST=0 $OFF" "-DHF_EARLY_EXIT=0" "$OFF" > $D/same_bits.txt 2>&1
for s in terrain_sunny terrain_overcast_light; do
PYOPENCL_CTX=0 $P bench/results/heightfield_speed/speed6_profile/prof.py bench/scenes/$s.toml 3 3 \
  "main|$OFF||horizons" "narrow|-DHF_SPREAD16_FAST=0||horizons" "spread16|-DHF_NARROW_FAST=0||horizons" \
  "both|||horizons" "main-noexit|-DHF_EARLY_EXIT=0 $OFF||horizons" "both-noexit|-DHF_EARLY_EXIT=0||horizons" > $D/prof_$s.txt 2>&1
done
